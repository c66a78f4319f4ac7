"""The ``efficientvit`` labeller: ADE20K labels at image resolution from an EfficientViT
segmentation model loaded from a **local** checkpoint (never downloaded at run time).

Pre-processing (as EfficientViT's ADE20K evaluation): RGB / 255, ImageNet mean/std, resized so
the short side is 512 and the long side is rounded up to a multiple of 32. Post-processing: the
model's logits (1, 150, H/8, W/8) are bilinearly upsampled to the *original* image size and the
arg-max is the label.

The numpy halves (``input_size``, ``normalize``, ``resize_bilinear``, ``labels_from_logits``)
are pure and tested here; the torch half runs wherever torch is installed (a tiny randomly
initialised network stands in for the real one in the tests). Importing ``efficientvit`` is only
needed to *build* the real model (``efficientvit.seg_model_zoo``).
"""

from __future__ import annotations

import importlib
import math
from pathlib import Path
from typing import Any

import numpy as np

from .backend import MissingBackend

MEAN = np.array([0.485, 0.456, 0.406], np.float32)
STD = np.array([0.229, 0.224, 0.225], np.float32)
NUM_CLASSES = 150
INSTALL_HINT = ("install torch, then EfficientViT from git (pip install "
                "'git+https://github.com/mit-han-lab/efficientvit.git'; it also imports segment_anything, "
                "omegaconf and triton), and give a local checkpoint path (e.g. efficientvit_seg_l1_ade20k.pt)")


def input_size(height: int, width: int, short: int = 512, multiple: int = 32) -> tuple[int, int]:
    """Network input (H', W'): short side ``short``, long side scaled alike and rounded **up**
    to a multiple of ``multiple``."""
    if height <= 0 or width <= 0:
        raise ValueError("image sides must be positive")
    if height <= width:
        return short, int(math.ceil(width * short / height / multiple) * multiple)
    return int(math.ceil(height * short / width / multiple) * multiple), short


def resize_bilinear(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Bilinear resize of (H, W[, C]) to ``size = (H', W')``, half-pixel centres
    (``align_corners=False``, like torch's ``interpolate``)."""
    h, w = img.shape[:2]
    H, W = size

    def axis(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = (np.arange(n_out, dtype=np.float64) + 0.5) * (n_in / n_out) - 0.5
        x = np.clip(x, 0.0, n_in - 1)
        i0 = np.floor(x).astype(np.int64)
        i1 = np.minimum(i0 + 1, n_in - 1)
        return i0, i1, (x - i0).astype(np.float32)

    y0, y1, fy = axis(h, H)
    x0, x1, fx = axis(w, W)
    a = img.astype(np.float32)
    if a.ndim == 2:
        a = a[..., None]
    top = a[y0][:, x0] * (1 - fx)[None, :, None] + a[y0][:, x1] * fx[None, :, None]
    bot = a[y1][:, x0] * (1 - fx)[None, :, None] + a[y1][:, x1] * fx[None, :, None]
    out = top * (1 - fy)[:, None, None] + bot * fy[:, None, None]
    return out if img.ndim == 3 else out[..., 0]


def normalize(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 → (1, 3, H', W') float32 network input (see ``input_size``)."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
    x = resize_bilinear(rgb.astype(np.float32) / 255.0, input_size(*rgb.shape[:2]))
    x = (x - MEAN) / STD
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None])


def labels_from_logits(logits: np.ndarray, height: int, width: int) -> np.ndarray:
    """(1, C, h, w) or (C, h, w) logits → (height, width) uint16 labels: bilinear upsampling of
    the logits, then arg-max over classes."""
    lg = logits[0] if logits.ndim == 4 else logits
    if lg.ndim != 3:
        raise ValueError(f"logits must be (C, h, w), got {logits.shape}")
    up = resize_bilinear(lg.transpose(1, 2, 0), (height, width))
    return up.argmax(axis=-1).astype(np.uint16)


def _require(names: tuple[str, ...]) -> dict[str, Any]:
    mods, missing = {}, []
    for n in names:
        try:
            mods[n] = importlib.import_module(n)
        except ImportError:
            missing.append(n)
    if missing:
        raise MissingBackend(f"the efficientvit labeller needs {', '.join(missing)}: {INSTALL_HINT}")
    return mods


class EfficientVitLabeller:
    """Callable ``rgb → labels``. Give ``model`` (any torch module with the EfficientViT seg
    interface: (1, 3, H', W') → (1, 150, H'/8, W'/8)) or ``checkpoint`` (+ ``model_name``)."""

    def __init__(self, checkpoint: str | Path | None = None, model_name: str = "efficientvit-seg-l1-ade20k",
                 device: str = "cpu", model: Any = None):
        self.torch = _require(("torch",))["torch"]
        self.device = device
        if model is None:
            if checkpoint is None:
                raise MissingBackend(f"the efficientvit labeller needs a local checkpoint path: {INSTALL_HINT}")
            path = Path(checkpoint)
            if not path.is_file():
                raise MissingBackend(f"EfficientViT checkpoint {path} does not exist (local files only)")
            if not model_name.endswith("-ade20k"):
                raise ValueError(f"{model_name}: riskfield needs ADE20K labels (a *-ade20k model)")
            zoo = _require(("efficientvit.seg_model_zoo",))["efficientvit.seg_model_zoo"]
            model = zoo.create_efficientvit_seg_model(model_name, pretrained=True, weight_url=str(path))
        self.model = model.to(device).eval()

    def logits(self, rgb: np.ndarray) -> Any:
        torch = self.torch
        with torch.inference_mode():
            x = torch.from_numpy(normalize(rgb)).to(self.device)
            return self.model(x)

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        torch = self.torch
        out = self.logits(rgb)
        if out.shape[1] != NUM_CLASSES:
            raise ValueError(f"the model gives {out.shape[1]} classes, ADE20K has {NUM_CLASSES}")
        with torch.inference_mode():
            up = torch.nn.functional.interpolate(out.float(), size=rgb.shape[:2], mode="bilinear",
                                                 align_corners=False)
            return up.argmax(dim=1)[0].to(torch.int32).cpu().numpy().astype(np.uint16)
