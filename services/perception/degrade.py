"""How a foundation model's output differs from ground truth, as a seeded random model.

Applied to a perfect frame (camera-frame pointmap, labels, pose) it produces what MASt3R-SLAM
plus EfficientViT would plausibly give:

* **depth noise growing with range** — each point moves along its pixel ray by
  ``n ~ N(0, σ(z))`` with ``σ(z) = a + b·z²`` (stereo-like quadratic growth), inflated at grazing
  incidence by ``1/max(cos θ, 0.2)``;
* **confidence from range and incidence** — ``C = 1 + c_gain·cos θ·exp(−z / z_scale)``: like
  MASt3R's ``1 + exp(·)`` confidences it is ≥ 1 on valid pixels, largest for near surfaces seen
  head-on; 0 where nothing was seen;
* **label noise at boundaries** — pixels within ``boundary_px`` of a label edge take the label of
  a random neighbour with probability ``p_boundary``;
* **occasional wrong labels** — per frame, each object class present is, with probability
  ``p_confuse``, relabelled as a plausible confusion (dog → cat-like ``animal`` stays, box →
  cabinet, chair → armchair, …) over a random window of its pixels, plus sparse salt noise
  ``p_salt``;
* **optional pose drift** — a random walk on translation and yaw applied to ``T_WC``;
* **optional SLAM world and odometry errors** (``SlamErrorConfig``, off by default) — SLAM's
  scale error and scale drift, its heading drift (``SlamWorld``), and wheel slip in the odometry
  perception aligns to (``OdometrySlip``).

θ is the angle between the viewing ray and the surface normal, estimated from the pointmap
itself (cross product of neighbouring points), as a real pipeline would have to. The per-pixel
part (incidence, noise, confidence) runs in compiled kernels (``kernels.incidence_kernel``,
``kernels.depth_noise_kernel``) on numpy's random draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import CERTAIN_CONFIDENCE, ade20k

from ..runtime.jit import require_numba
from . import kernels

_I = ade20k.INDEX
#: Plausible confusions of a segmentation network: class → classes it is mistaken for.
CONFUSIONS: dict[int, tuple[int, ...]] = {
    _I["animal"]: (_I["cushion"], _I["plaything"], _I["person"]),
    _I["person"]: (_I["curtain"], _I["apparel"], _I["animal"]),
    _I["ball"]: (_I["plaything"], _I["vase"], _I["pot"]),
    _I["box"]: (_I["cabinet"], _I["chest of drawers"], _I["base"]),
    _I["chair"]: (_I["armchair"], _I["swivel chair"], _I["stool"]),
    _I["table"]: (_I["desk"], _I["coffee table"], _I["counter"]),
    _I["sofa"]: (_I["armchair"], _I["bed"], _I["cushion"]),
    _I["cabinet"]: (_I["wardrobe"], _I["chest of drawers"], _I["shelf"]),
    _I["bed"]: (_I["sofa"], _I["blanket"], _I["pillow"]),
}
#: Structure that is never relabelled wholesale (a network rarely confuses whole walls).
STRUCTURE = {_I["wall"], _I["floor"], _I["ceiling"]}


@dataclass(frozen=True)
class DegradationConfig:
    noise_a: float = 0.005  # m
    noise_b: float = 0.004  # 1/m
    c_gain: float = CERTAIN_CONFIDENCE - 1.0  # the most confident pixel is as certain as a truth frame
    z_scale: float = 4.0  # m
    boundary_px: int = 2
    p_boundary: float = 0.3
    p_confuse: float = 0.05
    p_salt: float = 0.001
    drift_t: float = 0.0  # m per frame (σ of the translation random walk)
    drift_yaw: float = 0.0  # rad per frame

    def __post_init__(self) -> None:
        for name, v in self.__dict__.items():
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"degradation {name} must be finite and non-negative")
        for name in ("p_boundary", "p_confuse", "p_salt"):
            if getattr(self, name) > 1:
                raise ValueError(f"degradation {name} is a probability")

    @classmethod
    def perfect(cls) -> DegradationConfig:
        """No degradation at all (ground truth through the same code path)."""
        return cls(0.0, 0.0, 0.0, 4.0, 0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def sigma(self, z: np.ndarray) -> np.ndarray:
        return self.noise_a + self.noise_b * z * z


def boundary_mask(labels: np.ndarray, width: int) -> np.ndarray:
    """Pixels within ``width`` pixels (Chebyshev) of a different label."""
    edge = np.zeros(labels.shape, bool)
    if width <= 0:
        return edge
    d = labels[:, 1:] != labels[:, :-1]
    edge[:, 1:] |= d
    edge[:, :-1] |= d
    d = labels[1:] != labels[:-1]
    edge[1:] |= d
    edge[:-1] |= d
    out = edge.copy()
    for _ in range(width - 1):  # grow by one pixel per pass
        grown = out.copy()
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        out = grown
    return out


@dataclass
class Observation:
    """One degraded frame: pointmap (H, W, 3) camera frame, confidence (H, W), labels (H, W),
    published pose (with drift), valid mask."""

    points: np.ndarray
    confidence: np.ndarray
    labels: np.ndarray
    T_WC: np.ndarray
    valid: np.ndarray


class Degrader:
    def __init__(self, config: DegradationConfig | None = None, seed: int = 0):
        require_numba("the degradation model")
        self.config = config or DegradationConfig()
        self.rng = np.random.default_rng(seed)
        self.drift = np.eye(4)

    def observe(self, points: np.ndarray, labels: np.ndarray, T_WC: np.ndarray, valid: np.ndarray) -> Observation:
        cfg = self.config
        valid = np.ascontiguousarray(valid & (points[..., 2] > 0))
        z = np.where(valid, points[..., 2], 0.0).astype(np.float64)
        p = np.ascontiguousarray(points, np.float32)
        cos = np.empty(valid.shape, np.float32)
        kernels.incidence_kernel(p, valid, cos)
        normal = self.rng.standard_normal(z.shape)  # drawn here, not in the kernel: numpy's stream
        e = np.exp(-z / cfg.z_scale)
        noisy, conf = np.empty(p.shape, np.float32), np.empty(valid.shape, np.float32)
        kernels.depth_noise_kernel((p, valid, z, cos), (normal, e),
                                   (float(cfg.noise_a), float(cfg.noise_b), float(cfg.c_gain)), (noisy, conf))
        return Observation(noisy, conf, self.degrade_labels(labels, valid), self._drifted(T_WC), valid)

    def degrade_labels(self, labels: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
        cfg, rng = self.config, self.rng
        out = labels.copy()
        h, w = labels.shape
        if cfg.p_boundary > 0 and cfg.boundary_px > 0:
            edge = boundary_mask(labels, cfg.boundary_px)
            pick = edge & (rng.random(labels.shape) < cfg.p_boundary)
            vv, uu = np.nonzero(pick)
            r = cfg.boundary_px
            dv = rng.integers(-r, r + 1, vv.size)
            du = rng.integers(-r, r + 1, uu.size)
            out[vv, uu] = labels[np.clip(vv + dv, 0, h - 1), np.clip(uu + du, 0, w - 1)]
        if cfg.p_confuse > 0:
            # the classes present, ascending: a bincount of the uint16 labels is a few times faster
            # than np.unique's hash-and-sort and gives the same sequence
            present = np.flatnonzero(np.bincount(labels.ravel())) if labels.dtype.kind == "u" else np.unique(labels)
            for lab in present:
                lab = int(lab)
                if lab in STRUCTURE or lab >= ade20k.NUM_CLASSES or rng.random() >= cfg.p_confuse:
                    continue
                wrong = int(rng.choice(CONFUSIONS.get(lab, (_I["box"],))))
                vs, us = np.nonzero(labels == lab)
                k = int(rng.integers(vs.size))
                v0, u0 = int(vs[k]), int(us[k])  # the window is centred on the object
                hh, ww = rng.integers(h // 8, h // 2 + 1), rng.integers(w // 8, w // 2 + 1)
                window = np.zeros(labels.shape, bool)
                window[max(0, v0 - hh // 2):v0 + hh // 2, max(0, u0 - ww // 2):u0 + ww // 2] = True
                out[window & (labels == lab)] = wrong
        if cfg.p_salt > 0:
            salt = rng.random(labels.shape) < cfg.p_salt
            out[salt] = rng.integers(0, ade20k.NUM_CLASSES, int(salt.sum()))
        # Noise never invents "nothing seen" on a seen pixel, nor labels where nothing was seen.
        out = np.where(out >= ade20k.NUM_CLASSES, labels, out)
        if valid is not None:
            out = np.where(valid, out, labels)
        return out.astype(np.uint16)

    def _drifted(self, T_WC: np.ndarray) -> np.ndarray:
        cfg = self.config
        if cfg.drift_t > 0 or cfg.drift_yaw > 0:
            step = np.eye(4)
            a = self.rng.normal(0.0, cfg.drift_yaw) if cfg.drift_yaw > 0 else 0.0
            step[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
            if cfg.drift_t > 0:
                step[:3, 3] = self.rng.normal(0.0, cfg.drift_t, 3) * np.array([1.0, 1.0, 0.2])
            self.drift = self.drift @ step
        return self.drift @ T_WC


@dataclass(frozen=True)
class SlamErrorConfig:
    """How a monocular SLAM's world differs from the metric one, and odometry from the truth. All off
    by default (the identity: ``SimBackend`` then publishes exactly what it did without them).

    * ``slam_scale`` — SLAM's scale s at the first image: its world is the true one scaled by s
      about the first camera (MASt3R-SLAM keeps the first keyframe's scale);
    * ``scale_drift`` — σ of a random walk of log s per √m of camera travel (relative per √m);
    * ``yaw_drift`` — σ (rad per √m) of a random walk of SLAM's heading about the vertical;
    * ``odom_slip`` — wheel odometry overstates every step of travel by this fraction (slip of
      driven wheels), the pose perception aligns to.
    """

    slam_scale: float = 1.0
    scale_drift: float = 0.0  # per √m
    yaw_drift: float = 0.0  # rad per √m
    odom_slip: float = 0.0  # fraction

    def __post_init__(self) -> None:
        if not (math.isfinite(self.slam_scale) and self.slam_scale > 0):
            raise ValueError("slam_scale must be finite and positive")
        for name in ("scale_drift", "yaw_drift", "odom_slip"):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be finite and non-negative")

    @property
    def is_identity(self) -> bool:
        return self.slam_scale == 1.0 and self.scale_drift == 0.0 and self.yaw_drift == 0.0

    @classmethod
    def bench(cls, slam_scale: float) -> SlamErrorConfig:
        """``riskfield bench scale``'s drifting SLAM: 1 %/√m of scale, 0.01 rad/√m of heading, 1 % slip."""
        return cls(slam_scale, 0.01, 0.01, 0.01)


class SlamWorld:
    """A drifting SLAM's world, seeded: each step of true camera travel Δp becomes s·R(ψ)·Δp in SLAM's
    world while s and ψ random-walk (``SlamErrorConfig``); near the current camera the true → SLAM map
    is the similarity x ↦ s·R(ψ)·(x − p) + p_slam (``to_slam``)."""

    def __init__(self, config: SlamErrorConfig, seed: int = 0):
        self.config = config
        self.rng = np.random.default_rng([seed, 0x5CA1E])  # its own stream: the degrader's draws stay
        self.log_s = math.log(config.slam_scale)
        self.yaw = 0.0
        self.p_true: np.ndarray | None = None
        self.p_slam: np.ndarray | None = None
        self.travelled = 0.0

    @property
    def scale(self) -> float:
        return math.exp(self.log_s)

    def step(self, T_WC_true: np.ndarray) -> None:
        p = np.asarray(T_WC_true[:3, 3], np.float64)
        if self.p_true is None:
            self.p_true, self.p_slam = p.copy(), p.copy()  # anchored at the first camera
            return
        dp = p - self.p_true
        ds = float(np.linalg.norm(dp))
        c = self.config
        if ds > 0:
            if c.scale_drift > 0:
                self.log_s += self.rng.normal(0.0, c.scale_drift * math.sqrt(ds))
            if c.yaw_drift > 0:
                self.yaw += self.rng.normal(0.0, c.yaw_drift * math.sqrt(ds))
        assert self.p_slam is not None
        self.p_slam = self.p_slam + self.scale * _yaw(self.yaw) @ dp
        self.p_true = p.copy()
        self.travelled += ds

    def to_slam(self, T_WC: np.ndarray) -> tuple[np.ndarray, float]:
        """A camera pose (true world) in SLAM's world, and the factor its camera-frame points take."""
        assert self.p_true is not None and self.p_slam is not None, "step() first"
        R = _yaw(self.yaw)
        out = np.eye(4)
        out[:3, :3] = R @ T_WC[:3, :3]
        out[:3, 3] = self.scale * R @ (T_WC[:3, 3] - self.p_true) + self.p_slam
        return out, self.scale


class OdometrySlip:
    """Wheel odometry that overstates travel by ``slip``: each true step Δp of the base is
    (1 + slip)·Δp; the heading stays true."""

    def __init__(self, slip: float):
        self.slip = slip
        self.p_true: np.ndarray | None = None
        self.p_odom: np.ndarray | None = None

    def pose(self, T_true: np.ndarray) -> np.ndarray:
        p = np.asarray(T_true[:3, 3], np.float64)
        if self.p_true is None or self.p_odom is None:
            self.p_true, self.p_odom = p.copy(), p.copy()
        else:
            self.p_odom = self.p_odom + (1.0 + self.slip) * (p - self.p_true)
            self.p_true = p.copy()
        out = np.array(T_true, np.float64)
        out[:3, 3] = self.p_odom
        return out


def _yaw(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
