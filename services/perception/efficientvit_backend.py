"""The ``efficientvit`` labeller: ADE20K labels at image resolution from an EfficientViT
segmentation model loaded from a **local** checkpoint (never downloaded at run time).

Pre-processing as EfficientViT's ADE20K evaluation (mit-han-lab/efficientvit at de7d773,
``applications/efficientvit_seg/eval_efficientvit_seg_model.py``, ``ADE20KDataset.__getitem__``
and ``ToTensor``): the uint8 RGB image is resized with **cubic** interpolation (``cv2.INTER_CUBIC``)
so the short side is 512 and the long side is rounded up to a multiple of 32, then divided by 255
and normalised with the ImageNet mean/std. Post-processing: the logits (1, 150, H/8, W/8) are
upsampled to the *original* image size with upstream's ``efficientvit/models/utils/network.py``
``resize``, whose default mode is bicubic, and the arg-max is the label.

Both cubic resamplings use Keys' kernel with a = −0.75 at half-pixel centres with clamped borders,
what OpenCV's ``INTER_CUBIC`` and torch's ``bicubic`` (``align_corners=False``) compute. The numpy
halves (``input_size``, ``normalize``, ``resize_cubic``, ``labels_from_logits``) are pure and tested
here; the torch half runs wherever torch is installed (a tiny randomly initialised network stands in
for the real one in the tests). Importing ``efficientvit`` is only needed to *build* the real model
(``efficientvit.seg_model_zoo.create_efficientvit_seg_model``). The default model is l2, the
authors' choice.
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
                "omegaconf and triton), and give a local checkpoint path (e.g. efficientvit_seg_l2_ade20k.pt)")


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


def _cubic_weights(n_in: int, n_out: int, a: float = -0.75) -> tuple[np.ndarray, np.ndarray]:
    """Taps (n_out, 4) and weights (n_out, 4) of Keys' cubic kernel along one axis.

    Source coordinate x = (i + ½)·n_in/n_out − ½, taps ⌊x⌋−1 … ⌊x⌋+2 clamped to the image, and
    with t the distance to a tap: W(t) = (a+2)|t|³ − (a+3)|t|² + 1 for |t| ≤ 1,
    a|t|³ − 5a|t|² + 8a|t| − 4a for 1 < |t| < 2.
    """
    x = (np.arange(n_out, dtype=np.float64) + 0.5) * (n_in / n_out) - 0.5
    x0 = np.floor(x)
    f = x - x0
    t = np.stack([1 + f, f, 1 - f, 2 - f], axis=1)
    w = np.where(t <= 1, ((a + 2) * t - (a + 3)) * t * t + 1, ((a * t - 5 * a) * t + 8 * a) * t - 4 * a)
    taps = np.clip(x0[:, None].astype(np.int64) + np.arange(-1, 3)[None, :], 0, n_in - 1)
    return taps, w


def resize_cubic(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Cubic resize of (H, W[, C]) to ``size = (H', W')`` (Keys, a = −0.75, half-pixel centres,
    clamped borders), separable, in float32. A uint8 image comes back rounded and saturated to
    uint8, as ``cv2.resize(..., interpolation=cv2.INTER_CUBIC)`` returns it."""
    h, w = img.shape[:2]
    H, W = size
    a = img.astype(np.float32)
    if a.ndim == 2:
        a = a[..., None]
    ty, wy = _cubic_weights(h, H)
    tx, wx = _cubic_weights(w, W)
    rows = np.einsum("ok,okwc->owc", wy.astype(np.float32), a[ty])
    out = np.einsum("ok,hokc->hoc", wx.astype(np.float32), rows[:, tx])
    if img.dtype == np.uint8:
        out = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return out if img.ndim == 3 else out[..., 0]


def normalize(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 → (1, 3, H', W') float32 network input (see ``input_size``)."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
    # Upstream resizes the uint8 image (cubic), then ToTensor divides by 255 and normalises.
    x = resize_cubic(rgb, input_size(*rgb.shape[:2])).astype(np.float32) / 255.0
    x = (x - MEAN) / STD
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None])


def labels_from_logits(logits: np.ndarray, height: int, width: int) -> np.ndarray:
    """(1, C, h, w) or (C, h, w) logits → (height, width) uint16 labels: bicubic upsampling of
    the logits (upstream ``resize``'s default mode), then arg-max over classes."""
    lg = logits[0] if logits.ndim == 4 else logits
    if lg.ndim != 3:
        raise ValueError(f"logits must be (C, h, w), got {logits.shape}")
    up = resize_cubic(lg.transpose(1, 2, 0).astype(np.float32), (height, width))
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

    def __init__(self, checkpoint: str | Path | None = None, model_name: str = "efficientvit-seg-l2-ade20k",
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
            # efficientvit/models/utils/network.py resize(): bicubic by default.
            up = torch.nn.functional.interpolate(out.float(), size=rgb.shape[:2], mode="bicubic",
                                                 align_corners=False)
            return up.argmax(dim=1)[0].to(torch.int32).cpu().numpy().astype(np.uint16)
