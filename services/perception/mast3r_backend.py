"""The ``mast3r`` geometry backend: an adapter to MASt3R-SLAM (rmurai0610/MASt3R-SLAM, read at
commit b0ae540; see ``shared/reference/mast3r_efficientvit.md``). GPU only; imported lazily.

The loop is upstream's ``main.py`` ``__main__`` in its single-thread form (global optimisation and
relocalisation run right after the frame that needs them, as ``config["single_thread"]`` makes the
main loop wait for them), driven one camera image at a time:

* **config** — upstream keeps a module-level ``config = {}`` that ``FrameTracker`` and
  ``create_frame`` read (``mast3r_slam/config.py``); it is always loaded: the installed
  checkout's own ``config/base.yaml`` (or ``mast3r_config``), then our overrides merged in place
  with upstream's ``merge_config`` (``AUTHORS_OVERRIDES``: the authors' ×10 subsampling).
  ``dataset.subsample`` = N keeps every N-th image, as upstream's dataloader ``subsample`` does.
* **modes** (``mast3r_slam/frame.py`` ``Mode``) — INIT: mono inference, first keyframe;
  TRACKING: ``FrameTracker.track``; when it answers ``try_reloc`` the backend switches to RELOC:
  mono inference on each frame and ``relocalise`` (upstream ``main.py`` ``relocalization``) until
  a retrieved keyframe accepts it, then back to TRACKING.
* **initial pose guess** — the last *tracked* frame's pose (upstream: ``states.get_frame().T_WC``),
  identity for the first frame; not the last keyframe's.
* **confidence** — a keyframe's ``C`` is the *sum* over its ``N`` fused observations
  (``Frame.update_pointmap``, ``weighted_pointmap``); messages carry the average
  ``get_average_conf()`` = C/N, and pixels below ``c_conf`` (default 1.5, upstream's
  ``WindowMsg.C_conf_threshold`` used with the average in ``evaluate.save_reconstruction``)
  get confidence 0, so the mapper skips them.
* **map updates** — each message has a ``kind`` (the keyframe protocol, see the README): a new
  keyframe once (``keyframe_new``); a ``keyframe_update`` with its full pointmap when global
  optimisation re-posed it or tracking refined its pointmap; a ``tracking`` frame otherwise.
  Re-posed keyframes are found by comparing each keyframe's ``T_WC`` with the pose last published:
  ``SharedKeyframes.update_T_WCs`` (called by ``FactorGraph.solve_GN_*``) does **not** set
  ``is_dirty``; only ``__setitem__`` does (the tracker's write-back of a refined keyframe), so
  ``get_dirty_idx()`` reports refined pointmaps, never poses. Refined keyframes are re-sent every
  ``update_every`` tracked frames and when the next keyframe starts (its final state).
* **pixel matches for labels** — ``track()`` keeps ``idx_f2k`` and the match qualities to
  itself; ``MatchRecorder`` wraps ``mast3r_match_asymmetric`` in the tracker's module while
  ``track()`` runs and keeps its outputs, from which ``Qk = sqrt(Qff[idx_f2k] · Qkf)`` and the
  trusted set ``valid_match_k & Qk > Q_conf`` follow (``fusion.transfer_labels``); the frame's
  labels are voted into the keyframe's label map (``fusion.vote_fuse``).
* **metric frames** — a pose is a lietorch Sim(3) whose ``data`` is ``(t, q xyzw, s)``
  (``mast3r_slam/lietorch_utils.py`` ``as_SE3`` splits it [3, 4, 1]) acting as ``p_W = s·R·X + t``;
  the wire contract wants a rigid camera → world transform, so the scale goes into the points:
  ``points = s · X_canon`` and ``T_WC = [R | t]``.
* **map frame** — SLAM's world is its first keyframe's camera (identity at INIT, optical axes).
  ``anchor(stamp_ns)``, when given, returns ``T_map_slam`` at that first image (the node passes
  the robot's odometry pose there times the camera extrinsic), so poses land in the robot's z-up
  map; every published pose is ``T_map_slam · T_WC``.
* **image geometry** — MASt3R resizes the long side to 512 and centre-crops to multiples of 16
  (``mast3r_utils.resize_img``); ``mast3r_crop`` computes the same box so labels computed on the
  original image are carried onto the keyframe grid (``labels_to_grid``).
"""

from __future__ import annotations

import contextlib
import copy
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from riskfield.protocol import Image, PerceptionFrame
from riskfield.protocol.messages import Header

from ..geometry.transforms import quat_to_matrix
from .backend import Labeller, MissingBackend, image_rgb
from .fusion import Q_CONF, match_confidence, transfer_labels, vote_fuse

C_CONF = 1.5
"""Threshold on the average confidence C/N: MASt3R-SLAM's ``WindowMsg.C_conf_threshold``
(``mast3r_slam/visualization.py``), applied to ``get_average_conf()`` in ``evaluate.save_reconstruction``."""


@dataclass(frozen=True)
class SlamParams:
    """How the SLAM loop runs and what it publishes: the torch device, the match quality a pixel
    needs to be fused into its keyframe (MASt3R-SLAM's Q_conf), the average confidence below which a
    published point gets confidence 0, a refined keyframe re-sent every ``update_every`` tracked
    frames, and the frame its poses are in."""

    device: str = "cuda:0"
    q_conf: float = Q_CONF
    c_conf: float = C_CONF
    update_every: int = 5
    frame_id: str = "map"
AUTHORS_OVERRIDES: dict[str, Any] = {"dataset": {"subsample": 10}}
"""What the authors' ``base_subsample10`` run changes in upstream's ``config/base.yaml``."""
REQUIRED_CONFIG = ("use_calib", "single_thread", "dataset", "tracking", "local_opt", "retrieval", "reloc")

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


class SlamFrame(NamedTuple):
    """One MASt3R frame as its message needs it: the canonical pointmap ``X_canon`` (H·W, 3), the
    *average* confidence ``C`` (``Frame.get_average_conf()``, not the running sum), the Sim(3)
    pose ``sim3`` (lietorch data), the labels per pixel, the image ``shape`` (H, W) and the
    keyframe index."""

    X_canon: np.ndarray
    C: np.ndarray
    sim3: np.ndarray
    labels: np.ndarray
    shape: tuple[int, int]
    keyframe_id: int


def keyframe_message(frame: SlamFrame, stamp_ns: int, frame_id: str = "map", kind: str | None = None,
                     c_conf: float = 0.0, T_map_slam: np.ndarray | None = None) -> PerceptionFrame:
    """A MASt3R frame as a ``PerceptionFrame`` (scale folded into the points; see module doc).
    Pixels below ``c_conf`` and non-finite points (the network's failures) get confidence 0 and a
    zero point. ``T_map_slam`` places SLAM's world (its first camera) in the map frame."""
    height, width = frame.shape
    T, s = sim3_pose(frame.sim3)
    if T_map_slam is not None:
        T = np.asarray(T_map_slam, np.float64) @ T
    X = np.asarray(frame.X_canon, np.float64).reshape(height, width, 3) * s
    Cf = np.asarray(frame.C, np.float64).reshape(height, width)
    bad = ~(np.isfinite(X).all(axis=-1) & np.isfinite(Cf))
    X[bad] = 0.0
    Cf = np.where(bad | (Cf < c_conf), 0.0, np.maximum(Cf, 0.0))
    return PerceptionFrame(header=Header(stamp_ns=stamp_ns, frame_id=frame_id), T_WC=T, points=X.astype(np.float32),
                           confidence=Cf.astype(np.float32),
                           labels=np.asarray(frame.labels, np.uint16).reshape(height, width),
                           keyframe_id=int(frame.keyframe_id), kind=kind)


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


# -- configuration and the startup check ----------------------------------------------------------


def checkout_config(mast3r_slam: Any) -> Path:
    """``config/base.yaml`` of the installed checkout (upstream installs with ``pip install -e .``,
    so the package sits in the clone next to ``config/``; ``main.py``'s ``--config`` default)."""
    return Path(mast3r_slam.__file__).resolve().parent.parent / "config" / "base.yaml"


def load_config(config_mod: Any, path: str | Path, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Fill upstream's module-level ``config`` from ``path``, then merge ``overrides`` into it.

    ``mast3r_slam/config.py``: ``load_config`` reads ``inherit:`` parents relative to the working
    directory (the authors run from the clone's root, ``inherit: "config/base.yaml"``), so it runs
    from there; ``set_global_config`` only ``update``s the top level, so the overrides go through
    ``merge_config``, which merges nested maps in place — the dict other modules imported by name
    stays the same object.
    """
    path = Path(path).resolve()
    if not path.is_file():
        raise MissingBackend(f"MASt3R-SLAM config {path} is missing")
    root = path.parent.parent if path.parent.name == "config" else path.parent
    with contextlib.chdir(root):
        config_mod.load_config(str(path))
    config_mod.merge_config(config_mod.config, copy.deepcopy(overrides or {}))
    cfg = config_mod.config
    missing = [k for k in REQUIRED_CONFIG if k not in cfg]
    if missing:
        raise MissingBackend(f"MASt3R-SLAM config {path} lacks {', '.join(missing)}")
    if cfg["use_calib"]:
        raise MissingBackend(f"MASt3R-SLAM config {path} sets use_calib: the adapter runs uncalibrated")
    return cfg


def startup_check(checkpoint_dir: str | Path, config: str | Path | None, device: str,
                  importer: Callable[[str], Any] = importlib.import_module) -> tuple[dict[str, Any], Path | None]:
    """Everything the backend needs, checked before anything loads: the modules, the three
    checkpoint files, the config file and a CUDA device. Raises one ``MissingBackend`` whose
    message (one line) names every missing piece."""
    mods, problems, missing_mods = {}, [], []
    for name in REQUIRED:
        try:
            mods[name] = importer(name)
        except ImportError as exc:
            missing_mods.append(f"{name} ({exc.name or exc})")
    if missing_mods:
        problems.append(f"cannot import {', '.join(missing_mods)}")
    ckpt = Path(checkpoint_dir)
    absent = [str(ckpt / n) for n in (CHECKPOINT, RETRIEVER, CODEBOOK) if not (ckpt / n).is_file()]
    if absent:
        problems.append(f"checkpoint {', '.join(absent)} missing")
    cfg_path: Path | None = Path(config) if config is not None else None
    if cfg_path is None and "mast3r_slam" in mods:
        cfg_path = checkout_config(mods["mast3r_slam"])
    if cfg_path is None:
        problems.append("config: the default config/base.yaml comes with the mast3r_slam checkout")
    elif not cfg_path.is_file():
        problems.append(f"config {cfg_path} missing")
    torch = mods.get("torch")
    if torch is not None and not (device.startswith("cuda") and torch.cuda.is_available()):
        problems.append(f"no CUDA device ({device!r}; torch.cuda.is_available() = {torch.cuda.is_available()})")
    if problems:
        hint = f" {INSTALL_HINT}" if missing_mods or absent else ""
        raise MissingBackend(f"the mast3r backend cannot start: {'; '.join(problems)}.{hint}")
    return mods, cfg_path


# -- the adapter (GPU; the loop runs on fakes in the tests) -----------------------------------------

INIT, TRACKING, RELOC = "init", "tracking", "reloc"  # upstream mast3r_slam/frame.py Mode (TERMINATED: n/a)


def _np(x: Any) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def _clone(x: Any) -> Any:
    return x.clone() if hasattr(x, "clone") else np.array(x, copy=True)


class Mast3rSlam:
    """Upstream's single-thread loop, one image at a time, producing map-update messages.

    ``m`` maps module names to modules (``REQUIRED``): the real ones on a GPU host, fakes of
    the same behaviour in the tests. ``model``/``retriever`` are what ``load_mast3r`` and
    ``load_retriever`` return.
    """

    def __init__(self, m: dict[str, Any], model: Any, retriever: Any, labeller: Labeller,
                 params: SlamParams = SlamParams(), T_map_slam: np.ndarray | None = None,
                 anchor: Callable[[int], np.ndarray] | None = None):
        self.m, self.model, self.retriever, self.labeller = m, model, retriever, labeller
        self.anchor = anchor
        self.cfg: dict[str, Any] = m["mast3r_slam.config"].config
        self.device, self.Q_conf, self.c_conf = params.device, params.q_conf, params.c_conf
        self.frame_id = params.frame_id
        self.update_every = max(1, int(params.update_every))
        self.T_map_slam = T_map_slam
        self.subsample = max(1, int(self.cfg["dataset"]["subsample"]))
        self.keyframes: Any = None
        self.tracker: Any = None
        self.graph: Any = None
        self.labels = KeyframeLabels()
        self.mode = INIT
        self.images = 0  # camera images seen (before subsampling)
        self.i = 0  # frames processed (upstream's frame_id)
        self.last_frame: Any = None  # upstream states.get_frame(): the last tracked frame
        self.crop: Crop | None = None
        self.published: dict[int, np.ndarray] = {}  # keyframe index → Sim3 data last sent
        self.refined: set[int] = set()
        self.since_update = 0
        self.relocalisations = 0
        self.recorder = MatchRecorder(m["mast3r_slam.tracker"].mast3r_match_asymmetric, _np)

    def _start(self, h: int, w: int) -> None:
        frame_mod = self.m["mast3r_slam.frame"]
        # SharedKeyframes takes a multiprocessing manager for its lock and counters (upstream main.py
        # passes torch.multiprocessing's); the fakes need none.
        mp = getattr(self.m["torch"], "multiprocessing", None)
        self._manager = mp.Manager() if mp is not None else None
        self.keyframes = frame_mod.SharedKeyframes(self._manager, h, w)
        self.tracker = self.m["mast3r_slam.tracker"].FrameTracker(self.model, self.keyframes, self.device)
        self.graph = self.m["mast3r_slam.global_opt"].FactorGraph(self.model, self.keyframes, None, self.device)

    def _track(self, frame: Any) -> tuple[bool, bool]:
        # Swap the recorder in for the duration of track(): mast3r_slam/tracker.py imports the
        # matcher by name (``from mast3r_slam.mast3r_utils import mast3r_match_asymmetric``).
        mod = self.m["mast3r_slam.tracker"]
        mod.mast3r_match_asymmetric = self.recorder
        try:
            add_new_kf, _, try_reloc = self.tracker.track(frame)
        finally:
            mod.mast3r_match_asymmetric = self.recorder.fn
        return bool(add_new_kf), bool(try_reloc)

    def _solve(self) -> None:
        if self.cfg["use_calib"]:
            self.graph.solve_GN_calib()
        else:
            self.graph.solve_GN_rays()

    def _optimise(self, idx: int) -> None:
        """Upstream ``main.py`` ``run_backend``, one task: the previous keyframe plus retrieved ones."""
        kf_idx = {idx - 1} if idx > 0 else set()
        retrieval = self.cfg["retrieval"]
        kf_idx |= {int(i) for i in self.retriever.update(self.keyframes[idx], add_after_query=True, k=retrieval["k"],
                                                         min_thresh=retrieval["min_thresh"])}
        kf_idx.discard(idx)
        if kf_idx:
            ii = sorted(kf_idx)
            self.graph.add_factors(ii, [idx] * len(ii), self.cfg["local_opt"]["min_match_frac"])
        self._solve()

    def _relocalise(self, frame: Any) -> bool:
        """Upstream ``main.py`` ``relocalization``: query the retrieval database (without adding),
        append the frame as a keyframe tied to the candidates; keep it if the factors hold
        (strict per ``reloc.strict``), starting from the first candidate's pose, else drop it."""
        retrieval, reloc = self.cfg["retrieval"], self.cfg["reloc"]
        kf_idx = [int(i) for i in self.retriever.update(frame, add_after_query=False, k=retrieval["k"],
                                                        min_thresh=retrieval["min_thresh"])]
        if not kf_idx:
            return False
        self.keyframes.append(frame)
        n_kf = len(self.keyframes)
        if not self.graph.add_factors([n_kf - 1] * len(kf_idx), kf_idx, reloc["min_match_frac"],
                                      is_reloc=reloc["strict"]):
            self.keyframes.pop_last()
            return False
        self.retriever.update(frame, add_after_query=True, k=retrieval["k"], min_thresh=retrieval["min_thresh"])
        self.keyframes.T_WC[n_kf - 1] = _clone(self.keyframes.T_WC[kf_idx[0]])
        self._solve()
        return True

    def _message(self, frame: Any, idx: int, labels: np.ndarray, kind: str, stamp_ns: int) -> PerceptionFrame:
        h, w = self.crop.shape if self.crop else (int(self.keyframes.h), int(self.keyframes.w))
        data = _np(frame.T_WC.data).reshape(-1)
        if kind != "tracking":
            self.published[idx] = data.copy()
        return keyframe_message(SlamFrame(_np(frame.X_canon), _np(frame.get_average_conf()), data, labels, (h, w), idx),
                                stamp_ns, self.frame_id, kind, self.c_conf, self.T_map_slam)

    def _new_keyframe(self, labels: np.ndarray, stamp_ns: int) -> PerceptionFrame:
        idx = len(self.keyframes) - 1
        self.labels.start(idx, labels)
        return self._message(self.keyframes[idx], idx, self.labels.labels[idx], "keyframe_new", stamp_ns)

    def _updates(self, stamp_ns: int, flush: bool, skip: set[int]) -> list[PerceptionFrame]:
        """Re-posed keyframes now; refined ones every ``update_every`` frames or on ``flush``."""
        self.refined |= {int(i) for i in _np(self.keyframes.get_dirty_idx()).reshape(-1).tolist()}
        due = set()
        for i, sent in self.published.items():
            if i not in skip and not np.allclose(_np(self.keyframes.T_WC[i]).reshape(-1), sent, rtol=0, atol=1e-6):
                due.add(i)
        if flush or self.since_update >= self.update_every:
            due |= self.refined
            self.refined = set()
            self.since_update = 0
        due = {i for i in due - skip if i in self.labels.labels and i < len(self.keyframes)}
        self.refined -= due
        return [self._message(self.keyframes[i], i, self.labels.labels[i], "keyframe_update", stamp_ns)
                for i in sorted(due)]

    def process(self, image: Image | None, truth: PerceptionFrame | None, stamp_ns: int) -> list[PerceptionFrame]:
        if image is None:
            return []
        self.images += 1
        if (self.images - 1) % self.subsample:
            return []
        rgb = image_rgb(image)
        crop = mast3r_crop(*rgb.shape[:2])
        if self.crop is None:
            self.crop = crop
            self._start(*crop.shape)
        elif crop != self.crop:
            raise ValueError(f"the image size changed to {rgb.shape[1]}x{rgb.shape[0]}")
        labels = labels_to_grid(self.labeller(rgb), crop)
        frame_mod, utils = self.m["mast3r_slam.frame"], self.m["mast3r_slam.mast3r_utils"]
        # Upstream main.py: the guess is the last tracked frame's pose (states.get_frame().T_WC).
        T_WC = (self.m["lietorch"].Sim3.Identity(1, device=self.device) if self.last_frame is None
                else self.last_frame.T_WC)
        frame = frame_mod.create_frame(self.i, rgb.astype(np.float32) / 255.0, T_WC, img_size=512, device=self.device)
        self.i += 1
        out: list[PerceptionFrame] = []
        new: set[int] = set()
        with self.m["torch"].inference_mode():
            if self.mode == INIT:
                if self.anchor is not None:
                    self.T_map_slam = np.asarray(self.anchor(stamp_ns), np.float64)
                X, C = utils.mast3r_inference_mono(self.model, frame)
                frame.update_pointmap(X, C)
                self.keyframes.append(frame)
                self.last_frame = frame
                out.append(self._new_keyframe(labels, stamp_ns))
                new.add(0)
                self._optimise(0)
                self.mode = TRACKING
            elif self.mode == TRACKING:
                add_new_kf, try_reloc = self._track(frame)
                self.last_frame = frame
                if try_reloc:
                    self.mode = RELOC  # the frame's pose is an unverified guess: not published
                else:
                    current = len(self.keyframes) - 1
                    idx_f2k, valid_k, Qk = self.recorder.matches()
                    self.labels.fuse(current, labels, idx_f2k, valid_k, Qk, self.Q_conf)
                    out.append(self._message(frame, current, labels, "tracking", stamp_ns))
                    self.since_update += 1
                    if add_new_kf:
                        out += self._updates(stamp_ns, flush=True, skip=set())  # the finished keyframe
                        self.keyframes.append(frame)
                        new.add(len(self.keyframes) - 1)
                        out.append(self._new_keyframe(labels, stamp_ns))
                        self._optimise(len(self.keyframes) - 1)
            else:  # RELOC, upstream main.py: mono inference, then the back end's relocalization()
                X, C = utils.mast3r_inference_mono(self.model, frame)
                frame.update_pointmap(X, C)
                self.last_frame = frame
                if self._relocalise(frame):
                    self.relocalisations += 1
                    self.mode = TRACKING
                    new.add(len(self.keyframes) - 1)
                    out.append(self._new_keyframe(labels, stamp_ns))
            out += self._updates(stamp_ns, flush=False, skip=new)
        return out


class Mast3rBackend:
    """The ``mast3r`` backend: startup check, config, models, then ``Mast3rSlam``."""

    needs_truth = False

    def __init__(self, labeller: Labeller, checkpoint_dir: str | Path = "checkpoints", config: str | Path | None = None,
                 params: SlamParams = SlamParams(), overrides: dict[str, Any] | None = None,
                 T_map_slam: np.ndarray | None = None, anchor: Callable[[int], np.ndarray] | None = None):
        device = params.device
        m, cfg_path = startup_check(checkpoint_dir, config, device)
        assert cfg_path is not None
        load_config(m["mast3r_slam.config"], cfg_path, AUTHORS_OVERRIDES if overrides is None else overrides)
        ckpt = Path(checkpoint_dir)
        utils = m["mast3r_slam.mast3r_utils"]
        model = utils.load_mast3r(str(ckpt / CHECKPOINT), device=device)
        retriever = utils.load_retriever(model, str(ckpt / RETRIEVER), device=device)
        self.slam = Mast3rSlam(m, model, retriever, labeller, params, T_map_slam, anchor)

    def process(self, image: Image | None, truth: PerceptionFrame | None, stamp_ns: int) -> list[PerceptionFrame]:
        return self.slam.process(image, truth, stamp_ns)
