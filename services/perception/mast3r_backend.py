"""The ``mast3r`` geometry backend: an adapter to MASt3R-SLAM (rmurai0610/MASt3R-SLAM, read at
commit b0ae540; see ``shared/reference/mast3r_efficientvit.md``). GPU only; imported lazily.

What the adapter adds to MASt3R-SLAM's own loop (first frame: mono inference, later frames:
``FrameTracker.track``, new keyframes appended to ``SharedKeyframes``):

* **pixel matches for labels** — ``track()`` keeps ``idx_f2k`` and the match qualities to
  itself; ``MatchRecorder`` wraps ``mast3r_match_asymmetric`` in the tracker's module while
  ``track()`` runs and keeps its outputs, from which ``Qk = sqrt(Qff[idx_f2k] · Qkf)`` and the
  trusted set ``valid_match_k & Qk > Q_conf`` follow (``fusion.transfer_labels``). The frame's
  labels are then voted into the keyframe's label map (``fusion.vote_fuse``). The geometry
  fusion of eq. (2) is MASt3R-SLAM's own (``Frame.update_pointmap``, ``weighted_pointmap``).
* **metric frames** — a keyframe's pose is a Sim(3) ``T_WC = (t, q xyzw, s)`` acting as
  ``p_W = s·R·X + t``; the wire contract wants a rigid camera → world transform, so the scale
  goes into the points: ``points = s · X_canon`` (camera frame) and ``T_WC = [R | t]``.
* **re-optimised keyframes** — after global optimisation, keyframes the backend moved
  (``get_dirty_idx()``) are published again with their new pose and the same ``keyframe_id``.
* **image geometry** — MASt3R resizes the long side to 512 and centre-crops to multiples of 16;
  ``mast3r_crop`` computes the same box so labels computed on the original image are carried
  onto the keyframe grid (``labels_to_grid``).

Global optimisation runs synchronously after each new keyframe (MASt3R-SLAM's single-thread
mode) instead of in a spawned process: simpler to own, slower per keyframe.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from riskfield.protocol import Image, PerceptionFrame
from riskfield.protocol.messages import Header

from ..geometry.transforms import quat_to_matrix
from .backend import Labeller, MissingBackend, image_rgb
from .fusion import Q_CONF, match_confidence, transfer_labels, vote_fuse

REQUIRED = ("torch", "lietorch", "mast3r_slam", "mast3r_slam.frame", "mast3r_slam.tracker", "mast3r_slam.mast3r_utils",
            "mast3r_slam.global_opt", "mast3r_slam.config")
INSTALL_HINT = (
    "MASt3R-SLAM runs on a CUDA GPU only: Python 3.11, torch 2.5.x with CUDA, then in a clone of "
    "rmurai0610/MASt3R-SLAM: pip install -e thirdparty/mast3r; pip install -e thirdparty/in3d; "
    "pip install --no-build-isolation -e . ; lietorch from git (princeton-vl/lietorch, not the PyPI package); "
    "checkpoints in <checkpoint_dir>/MASt3R_ViTLarge_BaseDecoder_512_catmlpdpt_metric*.pth/.pkl"
)
CHECKPOINT = "MASt3R_ViTLarge_BaseDecoder_512_catmlpdpt_metric.pth"
RETRIEVER = "MASt3R_ViTLarge_BaseDecoder_512_catmlpdpt_metric_retrieval_trainingfree.pth"
CODEBOOK = "MASt3R_ViTLarge_BaseDecoder_512_catmlpdpt_metric_retrieval_codebook.pkl"


def require_mast3r() -> dict[str, Any]:
    """Import every module the adapter needs, or one ``MissingBackend`` naming all that are missing."""
    mods, missing = {}, []
    for name in REQUIRED:
        try:
            mods[name] = importlib.import_module(name)
        except ImportError as exc:
            missing.append(f"{name} ({exc.name or exc})")
    if missing:
        raise MissingBackend(f"the mast3r backend cannot import {', '.join(missing)}. {INSTALL_HINT}")
    return mods


# -- pure parts ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Crop:
    """MASt3R's image geometry: resize (H, W) → (rh, rw), then keep rows y0:y1, columns x0:x1."""

    rh: int
    rw: int
    y0: int
    y1: int
    x0: int
    x1: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.y1 - self.y0, self.x1 - self.x0


def mast3r_crop(height: int, width: int, size: int = 512, square_ok: bool = False) -> Crop:
    """The long side is scaled to ``size`` (sides rounded to the nearest pixel), then a centred
    crop whose sides are multiples of 16; a square image is cropped to 4:3 unless ``square_ok``.
    640×480 → 512×384."""
    s = size / max(height, width)
    rw, rh = round(width * s), round(height * s)
    cx, cy = rw // 2, rh // 2
    halfw, halfh = ((2 * cx) // 16) * 8, ((2 * cy) // 16) * 8
    if not square_ok and rw == rh:
        halfh = int(3 * halfw / 4)
    return Crop(rh, rw, cy - halfh, cy + halfh, cx - halfw, cx + halfw)


def labels_to_grid(labels: np.ndarray, crop: Crop) -> np.ndarray:
    """Labels of the original image carried onto MASt3R's grid: nearest-neighbour resize (labels
    must never be interpolated) at pixel centres, then the crop."""
    h, w = labels.shape
    ys = np.minimum(((np.arange(crop.y0, crop.y1) + 0.5) * h / crop.rh).astype(np.int64), h - 1)
    xs = np.minimum(((np.arange(crop.x0, crop.x1) + 0.5) * w / crop.rw).astype(np.int64), w - 1)
    return labels[ys][:, xs]


def sim3_pose(data: np.ndarray) -> tuple[np.ndarray, float]:
    """lietorch ``Sim3`` data ``(tx, ty, tz, qx, qy, qz, qw, s)`` → (rigid 4x4 ``[R | t]``, scale s)."""
    d = np.asarray(data, np.float64).reshape(-1)
    if d.shape != (8,) or not np.isfinite(d).all():
        raise ValueError(f"a Sim3 needs 8 finite numbers, got {d.shape}")
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = quat_to_matrix(d[3:7]), d[:3]
    if not d[7] > 0:
        raise ValueError(f"Sim3 scale must be positive, got {d[7]}")
    return T, float(d[7])


def keyframe_message(X_canon: np.ndarray, C: np.ndarray, sim3: np.ndarray, labels: np.ndarray, height: int, width: int,
                     keyframe_id: int, stamp_ns: int, frame_id: str = "map") -> PerceptionFrame:
    """A MASt3R keyframe as a ``PerceptionFrame`` (scale folded into the points; see module doc).
    Non-finite points (the network's failures) get confidence 0 and a zero point."""
    T, s = sim3_pose(sim3)
    X = np.asarray(X_canon, np.float64).reshape(height, width, 3) * s
    Cf = np.asarray(C, np.float64).reshape(height, width)
    bad = ~(np.isfinite(X).all(axis=-1) & np.isfinite(Cf))
    X[bad] = 0.0
    Cf = np.where(bad, 0.0, np.maximum(Cf, 0.0))
    return PerceptionFrame(header=Header(stamp_ns=stamp_ns, frame_id=frame_id), T_WC=T, points=X.astype(np.float32),
                           confidence=Cf.astype(np.float32),
                           labels=np.asarray(labels, np.uint16).reshape(height, width),
                           keyframe_id=int(keyframe_id))


class MatchRecorder:
    """Wraps ``mast3r_match_asymmetric(model, frame, keyframe, idx_i2j_init=None)`` and keeps
    its outputs ``(idx_f2k, valid_match_k, Xff, Cff, Qff, Xkf, Ckf, Qkf)`` of the last call."""

    def __init__(self, fn: Any, to_numpy: Any = np.asarray):
        self.fn = fn
        self.to_numpy = to_numpy
        self.last: tuple | None = None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        out = self.fn(*args, **kwargs)
        self.last = out
        return out

    def matches(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(idx_f2k, valid_match_k, Qk)`` of the last call, flattened numpy arrays."""
        if self.last is None:
            raise RuntimeError("no match was recorded")
        idx_f2k, valid_k, _, _, Qff, _, _, Qkf = self.last
        idx = self.to_numpy(idx_f2k).reshape(-1).astype(np.int64)
        return idx, self.to_numpy(valid_k).reshape(-1).astype(bool), match_confidence(
            self.to_numpy(Qff), self.to_numpy(Qkf), idx)


class KeyframeLabels:
    """Fused label map and vote weights per keyframe index (the semantic half of the map)."""

    def __init__(self) -> None:
        self.labels: dict[int, np.ndarray] = {}
        self.weights: dict[int, np.ndarray] = {}

    def start(self, kf: int, labels: np.ndarray, weight: float | np.ndarray = 1.0) -> None:
        self.labels[kf] = np.asarray(labels, np.uint16).reshape(-1).copy()
        self.weights[kf] = np.broadcast_to(np.asarray(weight, np.float32), self.labels[kf].shape).copy()

    def fuse(self, kf: int, labels_frame: np.ndarray, idx_f2k: np.ndarray, valid_k: np.ndarray, Qk: np.ndarray,
             Q_conf: float = Q_CONF) -> np.ndarray:
        observed, trusted, q = transfer_labels(labels_frame, idx_f2k, valid_k, Qk, Q_conf)
        self.labels[kf], self.weights[kf] = vote_fuse(self.labels[kf], self.weights[kf], observed.astype(np.uint16),
                                                      q, trusted)
        return trusted


# -- the adapter (GPU) ---------------------------------------------------------------------------


class Mast3rBackend:
    needs_truth = False

    def __init__(self, labeller: Labeller, checkpoint_dir: str | Path = "checkpoints", config: str | Path | None = None,
                 device: str = "cuda:0", Q_conf: float = Q_CONF, frame_id: str = "map"):
        m = require_mast3r()
        ckpt = Path(checkpoint_dir)
        for name in (CHECKPOINT, RETRIEVER, CODEBOOK):
            if not (ckpt / name).is_file():
                raise MissingBackend(f"MASt3R-SLAM checkpoint {ckpt / name} is missing. {INSTALL_HINT}")
        self.m, self.torch, self.lietorch = m, m["torch"], m["lietorch"]
        if config is not None:
            m["mast3r_slam.config"].load_config(str(config))
        self.cfg = m["mast3r_slam.config"].config
        self.device, self.Q_conf, self.frame_id = device, Q_conf, frame_id
        self.labeller = labeller
        self.model = m["mast3r_slam.mast3r_utils"].load_mast3r(str(ckpt / CHECKPOINT), device=device)
        self.retriever = m["mast3r_slam.mast3r_utils"].load_retriever(self.model, str(ckpt / RETRIEVER), device=device)
        self.keyframes: Any = None
        self.tracker: Any = None
        self.graph: Any = None
        self.labels = KeyframeLabels()
        self.i = 0
        self.crop: Crop | None = None
        self.recorder = MatchRecorder(m["mast3r_slam.tracker"].mast3r_match_asymmetric,
                                      lambda t: t.detach().cpu().numpy() if hasattr(t, "detach") else np.asarray(t))

    def _start(self, h: int, w: int) -> None:
        import torch.multiprocessing as mp  # part of torch: present when require_mast3r() passed

        frame_mod = self.m["mast3r_slam.frame"]
        self._manager = mp.Manager()
        self.keyframes = frame_mod.SharedKeyframes(self._manager, h, w)
        self.tracker = self.m["mast3r_slam.tracker"].FrameTracker(self.model, self.keyframes, self.device)
        self.graph = self.m["mast3r_slam.global_opt"].FactorGraph(self.model, self.keyframes, None, self.device)

    def _track(self, frame: Any) -> tuple[bool, bool]:
        # Swap the recorder in for the duration of track(): the tracker calls the matcher by the
        # name it imported into its own module.
        mod = self.m["mast3r_slam.tracker"]
        mod.mast3r_match_asymmetric = self.recorder
        try:
            add_new_kf, _, try_reloc = self.tracker.track(frame)
        finally:
            mod.mast3r_match_asymmetric = self.recorder.fn
        return bool(add_new_kf), bool(try_reloc)

    def _optimise(self, idx: int) -> None:
        kf_idx = {idx - 1} if idx > 0 else set()
        retrieval = self.cfg["retrieval"]
        kf_idx |= set(self.retriever.update(self.keyframes[idx], add_after_query=True, k=retrieval["k"],
                                            min_thresh=retrieval["min_thresh"]))
        kf_idx.discard(idx)
        if kf_idx:
            self.graph.add_factors(sorted(kf_idx), [idx] * len(kf_idx), self.cfg["local_opt"]["min_match_frac"])
            self.graph.solve_GN_rays()

    def _message(self, idx: int, stamp_ns: int) -> PerceptionFrame:
        kf = self.keyframes[idx]
        h, w = self.crop.shape if self.crop else kf.uimg.shape[:2]
        to_np = self.recorder.to_numpy
        return keyframe_message(to_np(kf.X_canon), to_np(kf.C), to_np(kf.T_WC.data), self.labels.labels[idx], h, w,
                                idx, stamp_ns, self.frame_id)

    def process(self, image: Image | None, truth: PerceptionFrame | None, stamp_ns: int) -> list[PerceptionFrame]:
        if image is None:
            return []
        torch = self.torch
        rgb = image_rgb(image)
        crop = mast3r_crop(*rgb.shape[:2])
        if self.crop is None:
            self.crop = crop
            self._start(*crop.shape)
        labels = labels_to_grid(self.labeller(rgb), crop)
        frame_mod = self.m["mast3r_slam.frame"]
        T_WC = (self.lietorch.Sim3.Identity(1, device=self.device) if len(self.keyframes) == 0
                else self.keyframes.last_keyframe().T_WC)
        frame = frame_mod.create_frame(self.i, rgb.astype(np.float32) / 255.0, T_WC, img_size=512, device=self.device)
        self.i += 1
        out_idx: set[int] = set()
        with torch.inference_mode():
            if len(self.keyframes) == 0:
                X, C = self.m["mast3r_slam.mast3r_utils"].mast3r_inference_mono(self.model, frame)
                frame.update_pointmap(X, C)
                self.keyframes.append(frame)
                self.labels.start(0, labels)
                self._optimise(0)
                out_idx.add(0)
            else:
                add_new_kf, try_reloc = self._track(frame)
                current = len(self.keyframes) - 1
                if try_reloc:
                    return []  # tracking lost: publish nothing rather than a wrong pose
                idx_f2k, valid_k, Qk = self.recorder.matches()
                self.labels.fuse(current, labels, idx_f2k, valid_k, Qk, self.Q_conf)
                out_idx.add(current)
                if add_new_kf:
                    self.keyframes.append(frame)
                    new = len(self.keyframes) - 1
                    self.labels.start(new, labels)
                    self._optimise(new)
                    out_idx.add(new)
            dirty = self.keyframes.get_dirty_idx()
            out_idx |= {int(i) for i in (dirty.tolist() if hasattr(dirty, "tolist") else dirty)}
        return [self._message(i, stamp_ns) for i in sorted(out_idx) if i in self.labels.labels]
