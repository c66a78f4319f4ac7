"""SLAM's world → the odometry frame: the similarity perception puts between them, estimated online.

A monocular SLAM reconstruction is known only up to a similarity: MASt3R-SLAM keeps its first
keyframe's scale and lets it drift (its maintainers say so, upstream issues #77 and #136). Wheel
odometry is metric, and the map must live in its frame (REP 105: ``map → odom → base_link``). So
perception pairs, frame by frame, the camera position SLAM reports with the camera position odometry
implies (``T_odom_base · T_base_camera``, the platform's ``CameraMount``) and fits the similarity
``y = s·R·x + t`` over a sliding window of those pairs:

* **Umeyama's closed form** (S. Umeyama, "Least-squares estimation of transformation parameters
  between two point patterns", IEEE TPAMI 13(4):376–380, 1991, eqs. 34–43): with the centred
  patterns' cross-covariance Σ_xy = U·D·Vᵀ, R = U·S·Vᵀ (S = diag(1, …, 1, −1) where det Σ_xy < 0,
  or, at rank m − 1, where det U·det V < 0), s = tr(D·S)/σ_x², t = μ_y − s·R·μ_x; the least-squares
  error is ε² = σ_y² − tr(D·S)²/σ_x² (eq. 43). :func:`umeyama`.
* A ground robot driving straight gives collinear camera positions, which fix no rotation about the
  line. The rotation then comes from the pairs' orientations (the chordal mean of
  ``R_odom·R_slamᵀ``, the SO(3) projection of their sum) and the scale and translation from Umeyama's
  formulas with that R (:func:`scale_given_rotation`).
* **Before the robot has moved** there is no baseline; the scale comes from the floor: the floor's
  SLAM points lie a median height below the camera that must be the camera's known height
  (:func:`floor_scale`). Both estimates, when there are both, are fused by their variances.

The scale's uncertainty is the least-squares one: with per-axis position noise σ² (the fit's
residual, never below ``position_sigma``²) over n pairs of spread σ_x², var(s) = σ²/(n·σ_x²); a
drifting SLAM adds, in quadrature, how far the newer half of the window's own scale is from the
whole window's. The translation is fitted on the newest pairs (``anchor_pairs``), so that the
present camera, where the map is being made, lands on odometry's.
Everything here is plain numpy, no I/O: the perception node feeds it and publishes ``estimate()``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from riskfield.protocol import Alignment, PerceptionFrame, ade20k
from riskfield.protocol.messages import Header

from ..geometry.transforms import matrix_to_quat


@dataclass(frozen=True)
class Similarity:
    """x ↦ scale·R·x + t."""

    scale: float = 1.0
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def apply(self, points: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(points, np.float64) @ self.R.T + self.t

    def pose(self, T: np.ndarray) -> np.ndarray:
        """The rigid pose of a camera posed by ``T`` (camera → SLAM world) in the target frame; its
        camera-frame points scale by ``scale``."""
        out = np.eye(4)
        out[:3, :3] = self.R @ T[:3, :3]
        out[:3, 3] = self.scale * self.R @ T[:3, 3] + self.t
        return out

    def inverse(self) -> Similarity:
        R = self.R.T
        return Similarity(1.0 / self.scale, R, -(R @ self.t) / self.scale)

    @property
    def is_identity(self) -> bool:
        return self.scale == 1.0 and bool(np.array_equal(self.R, np.eye(3))) and not self.t.any()


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[Similarity, float]:
    """The least-squares similarity with ``dst ≈ s·R·src + t`` and its mean squared error ε²
    (Umeyama 1991, eqs. 34–43; see the module doc). ``src``, ``dst``: (n, m) corresponding points,
    n ≥ 2 and the centred ``src`` not all zero. Without scale s = 1 (the rigid fit, eq. 39 with c = 1)."""
    x, y = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[0] < 2:
        raise ValueError(f"need n ≥ 2 corresponding points of one dimension, got {x.shape} and {y.shape}")
    n, m = x.shape
    mu_x, mu_y = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mu_x, y - mu_y
    var_x = float((xc * xc).sum()) / n  # eq. 36
    var_y = float((yc * yc).sum()) / n  # eq. 37
    if var_x <= 0.0:
        raise ValueError("the source points coincide: no scale or rotation is defined")
    cov = yc.T @ xc / n  # eq. 38, Σ_xy
    U, D, Vt = np.linalg.svd(cov)
    S = np.ones(m)
    rank = int((D > D[0] * 1e-12).sum()) if D[0] > 0 else 0
    if rank >= m - 1:
        # eq. 39 / 43: a reflection is corrected by flipping the smallest singular direction
        if (np.linalg.det(cov) < 0) if rank == m else (np.linalg.det(U) * np.linalg.det(Vt) < 0):
            S[-1] = -1.0
    R = U @ np.diag(S) @ Vt  # eq. 40
    trace_ds = float((D * S).sum())
    c = trace_ds / var_x if with_scale else 1.0  # eq. 42
    t = mu_y - c * R @ mu_x  # eq. 41
    if with_scale:
        err = var_y - trace_ds ** 2 / var_x  # eq. 43
    else:
        err = float(((yc - xc @ R.T) ** 2).sum()) / n
    return Similarity(c, R, t), max(err, 0.0)


def scale_given_rotation(src: np.ndarray, dst: np.ndarray, R: np.ndarray) -> tuple[Similarity, float]:
    """Umeyama's scale and translation (eqs. 41–42, with tr(D·S) = tr(Rᵀ·Σ_xy)) for a rotation known
    otherwise, and the mean squared error of the fit."""
    x, y = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    mu_x, mu_y = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mu_x, y - mu_y
    var_x = float((xc * xc).sum()) / len(x)
    if var_x <= 0.0:
        raise ValueError("the source points coincide: no scale is defined")
    c = float(np.trace(R.T @ (yc.T @ xc))) / len(x) / var_x
    if c <= 0:
        raise ValueError("the patterns point opposite ways under this rotation")
    t = mu_y - c * R @ mu_x
    err = float(((yc - c * xc @ R.T) ** 2).sum()) / len(x)
    return Similarity(c, R, t), err


def project_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation nearest (Frobenius) to a 3×3 matrix: the chordal mean of rotations summed into it."""
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0]) @ Vt


@dataclass(frozen=True)
class FloorScale:
    scale: float
    sigma: float  # relative
    points: int


def floor_scale(points: np.ndarray, up: np.ndarray, height: float, height_sigma: float = 0.0,
                min_points: int = 50, max_spread: float = 0.2) -> FloorScale | None:
    """The scale that puts the floor ``height`` below the camera. ``points`` (N×3, camera frame, SLAM
    units) are the floor's pixels; ``up`` is the floor's normal in the camera frame, known from the
    extrinsics. Each point's height below the camera is −up·p; their median is SLAM's camera height.
    The normal is not fitted: depth noise along the rays, largest at grazing incidence, tilts a fitted
    plane (a total-least-squares fit was 5 % off on the simulator's noise), while a point's height
    scales with its depth's error (p(1 + ε) lies h(1 + ε) below), so the median is unbiased. Only the
    nearer half counts: labels bleed across the floor's far edge, and an extrinsic pitch error grows
    with range. None without enough points, or when their heights spread by more than ``max_spread``
    of their median. ``sigma`` (relative) combines the spread of the heights
    (their MAD, /√N) and the height's own error (``height_sigma``)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    if len(p) < min_points or height <= 0:
        return None
    r = np.linalg.norm(p, axis=1)
    p = p[r <= np.median(r)]
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    below = -(p @ up)
    below = below[below > 0]
    if len(below) < min_points // 2:
        return None
    d = float(np.median(below))
    spread = 1.4826 * float(np.median(np.abs(below - d)))  # the MAD as a standard deviation
    if spread > max_spread * d:
        return None  # not a plane at one height below the camera (a wall, a mislabelled object)
    sigma = math.hypot(1.2533 * spread / math.sqrt(len(below)) / d, height_sigma / height)  # the median's σ
    return FloorScale(height / d, sigma, len(below))


@dataclass(frozen=True)
class AlignerConfig:
    window_m: float = 1.5  # odometry path length of the pairs kept
    max_pairs: int = 400
    min_step: float = 0.02  # m of camera travel between two pairs (a standing robot adds none)
    min_baseline: float = 0.3  # m of spread before the motion scale counts
    position_sigma: float = 0.005  # m: the least per-axis position noise assumed of SLAM and odometry
    converged_sigma: float = 0.01  # relative scale σ below which the estimate has converged
    floor_frames: int = 10  # floor scales averaged
    planar_ratio: float = 0.15  # second/first singular value of the positions below which they are a line
    anchor_pairs: int = 5  # the newest pairs the translation is fitted on

    def __post_init__(self) -> None:
        if not (self.window_m > 0 and self.max_pairs >= 2 and self.min_step >= 0 and self.min_baseline > 0
                and self.position_sigma > 0 and self.converged_sigma > 0 and self.floor_frames >= 1):
            raise ValueError("aligner: window_m, min_baseline, position_sigma, converged_sigma > 0, "
                             "max_pairs ≥ 2, floor_frames ≥ 1")


@dataclass(frozen=True)
class Estimate:
    similarity: Similarity
    scale_sigma: float  # relative; inf: nothing known
    residual: float  # m, RMS
    pairs: int
    baseline: float  # m
    source: str  # none | floor | motion | fused
    converged: bool

    def message(self, stamp_ns: int, frame_id: str = "odom") -> Alignment:
        sim = self.similarity
        return Alignment(header=Header(stamp_ns=stamp_ns, frame_id=frame_id), scale=sim.scale,
                         rotation=matrix_to_quat(sim.R), translation=tuple(sim.t.tolist()),
                         scale_sigma=min(self.scale_sigma, 1e6), residual=self.residual, pairs=self.pairs,
                         baseline=self.baseline, source=self.source, converged=self.converged)


class Aligner:
    """The sliding-window estimator of the SLAM → odometry similarity (module doc)."""

    def __init__(self, config: AlignerConfig | None = None):
        self.config = config or AlignerConfig()
        # (SLAM camera position, SLAM camera rotation, odometry camera position, odometry rotation, path m)
        self.pairs: deque[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]] = deque()
        self.floor: deque[FloorScale] = deque(maxlen=self.config.floor_frames)
        self.path = 0.0
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None

    def add_pair(self, T_slam_cam: np.ndarray, T_odom_cam: np.ndarray) -> None:
        """One camera seen by both: its pose in SLAM's world and the pose odometry gives it."""
        x, Rx = np.array(T_slam_cam[:3, 3], np.float64), np.array(T_slam_cam[:3, :3], np.float64)
        y, Ry = np.array(T_odom_cam[:3, 3], np.float64), np.array(T_odom_cam[:3, :3], np.float64)
        if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(Rx).all() and np.isfinite(Ry).all()):
            raise ValueError("a non-finite pose")
        self._last = (x, Rx, y, Ry)
        if self.pairs and np.linalg.norm(y - self.pairs[-1][2]) < self.config.min_step:
            return
        if self.pairs:
            self.path += float(np.linalg.norm(y - self.pairs[-1][2]))
        self.pairs.append((x, Rx, y, Ry, self.path))
        while len(self.pairs) > self.config.max_pairs or (
                len(self.pairs) > 2 and self.path - self.pairs[1][4] > self.config.window_m):
            self.pairs.popleft()

    def add_floor(self, measurement: FloorScale | None) -> None:
        if measurement is not None and math.isfinite(measurement.scale) and measurement.scale > 0:
            self.floor.append(measurement)

    def reset(self) -> None:
        """Forget everything (SLAM restarted, odometry jumped)."""
        self.pairs.clear()
        self.floor.clear()
        self._last = None

    def _floor(self) -> tuple[float, float] | None:
        if not self.floor:
            return None
        logs = np.log([f.scale for f in self.floor])
        w = 1.0 / np.square([max(f.sigma, 1e-9) for f in self.floor])
        mean = float((w * logs).sum() / w.sum())
        # the frames share the height's error: averaging them shrinks only the plane's part
        sigma = max(min(f.sigma for f in self.floor), float(1.0 / math.sqrt(w.sum())))
        return math.exp(mean), sigma

    def _motion(self) -> tuple[Similarity, float, float, float] | None:
        """(similarity, relative scale σ, RMS residual, baseline) from the window, or None."""
        c = self.config
        if len(self.pairs) < 3:
            return None
        x = np.array([p[0] for p in self.pairs])
        y = np.array([p[2] for p in self.pairs])
        yc = y - y.mean(axis=0)
        _, sv, Vt = np.linalg.svd(yc, full_matrices=False)
        baseline = float(np.ptp(yc @ Vt[0]))  # the extent along the main direction
        if baseline < c.min_baseline:
            return None
        if sv[1] >= c.planar_ratio * sv[0]:
            sim, err = umeyama(x, y)
        else:  # a line: the rotation from the orientations
            R = project_rotation(sum(p[3] @ p[1].T for p in self.pairs))
            try:
                sim, err = scale_given_rotation(x, y, R)
            except ValueError:
                return None
        n = len(x)
        var_x = float(((x - x.mean(axis=0)) ** 2).sum()) / n
        sigma2 = max(err / 3.0 * n / max(n - 2, 1), c.position_sigma ** 2)
        rel = math.sqrt(sigma2 / (n * var_x)) / sim.scale
        # A drifting SLAM changes its scale within the window, which the fit's σ does not see: the
        # newer half's own scale, where it has a baseline, says by how much (added in quadrature).
        half = n // 2
        if half >= 3 and np.ptp((y[half:] - y[half:].mean(axis=0)) @ Vt[0]) >= c.min_baseline / 2:
            try:
                recent, _ = scale_given_rotation(x[half:], y[half:], sim.R)
                rel = math.hypot(rel, recent.scale / sim.scale - 1.0)
            except ValueError:
                pass
        return sim, rel, math.sqrt(err), baseline

    def estimate(self) -> Estimate:
        """The current similarity and how well it is known (module doc)."""
        c = self.config
        motion = self._motion()
        floor = self._floor()
        if motion is None and self._last is None:
            return Estimate(Similarity(), math.inf, 0.0, 0, 0.0, "none", False)
        if motion is not None:
            sim, sigma, residual, baseline = motion
            source = "motion"
            s = sim.scale
            if floor is not None:
                wm, wf = 1.0 / sigma ** 2, 1.0 / floor[1] ** 2
                s = math.exp((wm * math.log(sim.scale) + wf * math.log(floor[0])) / (wm + wf))
                sigma = 1.0 / math.sqrt(wm + wf)
                source = "fused"
            # The translation where the map is made: on the newest pairs, so that a drifting SLAM's
            # present camera lands on odometry's (the window's centroid fit leaves it a residual off).
            x = np.array([p[0] for p in self.pairs])
            y = np.array([p[2] for p in self.pairs])
            k = min(len(x), c.anchor_pairs)
            sim = Similarity(s, sim.R, (y[-k:] - s * x[-k:] @ sim.R.T).mean(axis=0))
            residual = float(np.sqrt(((sim.apply(x) - y) ** 2).sum(axis=1).mean()))
            return Estimate(sim, sigma, residual, len(self.pairs), baseline, source, sigma < c.converged_sigma)
        # Not moved yet: the rotation from the newest pair's orientations, anchored at its camera.
        assert self._last is not None
        x, Rx, y, Ry = self._last
        R = project_rotation(Ry @ Rx.T)
        s, sigma, source = (floor[0], floor[1], "floor") if floor is not None else (1.0, math.inf, "none")
        return Estimate(Similarity(s, R, y - s * R @ x), sigma, 0.0, len(self.pairs), 0.0, source,
                        sigma < c.converged_sigma)


def align_frame(frame: PerceptionFrame, sim: Similarity) -> PerceptionFrame:
    """The frame in the target frame: its pose through the similarity, its camera-frame pointmap
    (``points`` or the compact ``depth``) scaled by it."""
    update: dict[str, object] = {"T_WC": sim.pose(np.asarray(frame.T_WC, np.float64))}
    if sim.scale != 1.0:
        if frame.points is not None:
            update["points"] = (np.asarray(frame.points, np.float32) * np.float32(sim.scale)).astype(np.float32)
        if frame.depth is not None:
            depth = np.asarray(frame.depth)
            update["depth"] = (depth.astype(np.float32) * np.float32(sim.scale)).astype(depth.dtype)
    return frame.model_copy(update=update)


class FrameAligner:
    """Perception's use of the estimator: pairs each current frame's SLAM pose with odometry's camera
    (``odometry`` poses the base; ``T_BC`` is the platform's camera mount), measures the floor's scale
    in it, and moves every frame — re-posed keyframes too — into the odometry frame with the newest
    estimate. ``odometry_view`` models odometry's own errors in simulation (``degrade.OdometrySlip``)."""

    FLOOR = ade20k.index("floor")

    def __init__(self, T_BC: np.ndarray, height_sigma: float, config: AlignerConfig | None = None,
                 odometry_view: object | None = None, max_state_age_s: float = 0.2):
        from .rgbd_backend import Odometry

        self.T_BC = np.asarray(T_BC, np.float64)
        self.height = float(self.T_BC[2, 3])  # base_link lies on the floor
        self.height_sigma = height_sigma
        self.up = self.T_BC[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # the floor's normal, camera frame
        self.aligner = Aligner(config)
        self.odometry = Odometry(max_state_age_s)
        self.odometry_view = odometry_view
        self.last: Estimate | None = None

    def align(self, frames: list[PerceptionFrame], stamp_ns: int) -> list[PerceptionFrame]:
        """The frames in the odometry frame; [] while nothing is known (no odometry near the image yet):
        a map of unknown scale is worse than none. Raises ValueError for a non-finite pose."""
        current = [f for f in frames if f.kind in (None, "tracking", "keyframe_new") and f.header.stamp_ns == stamp_ns]
        if current:
            try:
                T_odom_base = self.odometry.pose_at(stamp_ns)
            except ValueError:
                T_odom_base = None
            if T_odom_base is not None:
                if self.odometry_view is not None:
                    T_odom_base = self.odometry_view.pose(T_odom_base)  # type: ignore[attr-defined]
                f = current[0]
                self.aligner.add_pair(np.asarray(f.T_WC, np.float64), T_odom_base @ self.T_BC)
                self.aligner.add_floor(self.floor_of(f))
        est = self.aligner.estimate()
        if est.source == "none" or not math.isfinite(est.scale_sigma):
            return []
        self.last = est
        return [align_frame(f, est.similarity) for f in frames]

    def floor_of(self, frame: PerceptionFrame, step: int = 2) -> FloorScale | None:
        labels = np.asarray(frame.labels)[::step, ::step]
        conf = np.asarray(frame.confidence)[::step, ::step]
        floor = (labels == self.FLOOR) & (conf > 0)
        if not floor.any():
            return None
        points = np.asarray(frame.pointmap(), np.float32)[::step, ::step][floor]
        return floor_scale(points[points[:, 2] > 0], self.up, self.height, self.height_sigma)
