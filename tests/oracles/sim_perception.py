"""The ``sim`` perception backend's per-pixel steps in numpy, as test oracles of its compiled
kernels (``services/perception/kernels.py``): the degradation's incidence and depth noise
(``NumpyDegrader.observe``), keyframe matching (``NumpySimBackend.match``), fusion by eq. (2) and
(7)–(8) (``fuse``) and the current frame's fused labels and points (``NumpySimBackend.
_current_frame``), in the kernels' dtypes and operation order, so the published frames are
byte-identical (tests/perception/test_kernels.py)."""

from __future__ import annotations

import numpy as np

from riskfield.services.geometry.transforms import inverse as _inv
from riskfield.services.geometry.transforms import transform_points
from riskfield.services.perception.degrade import Degrader, Observation
from riskfield.services.perception.fusion import Q_CONF, KeyframeFusion, transfer_labels, vote_fuse
from riskfield.services.perception.sim_backend import Matches, SimBackend, SimBackendConfig, _Keyframe


def normals_from_pointmap(points: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit surface normals (H, W, 3) facing the camera, from neighbouring points, and where
    they are defined (the pixel and its horizontal and vertical neighbours valid)."""
    p = np.asarray(points, np.float32)
    # Central differences inside, one-sided at the image border (edge-padded copies).
    pp = np.pad(p, ((1, 1), (1, 1), (0, 0)), mode="edge")
    vp = np.pad(valid, 1, mode="edge")
    dx = pp[1:-1, 2:] - pp[1:-1, :-2]
    dy = pp[2:, 1:-1] - pp[:-2, 1:-1]
    ok = valid & vp[1:-1, 2:] & vp[1:-1, :-2] & vp[2:, 1:-1] & vp[:-2, 1:-1]
    n = np.empty_like(p)
    n[..., 0] = dx[..., 1] * dy[..., 2] - dx[..., 2] * dy[..., 1]
    n[..., 1] = dx[..., 2] * dy[..., 0] - dx[..., 0] * dy[..., 2]
    n[..., 2] = dx[..., 0] * dy[..., 1] - dx[..., 1] * dy[..., 0]
    norm = np.sqrt(n[..., 0] ** 2 + n[..., 1] ** 2 + n[..., 2] ** 2)
    ok &= norm > 1e-12
    # Divide by ±norm: unit length, and flipped to face the camera (n·p < 0).
    facing = n[..., 0] * p[..., 0] + n[..., 1] * p[..., 1] + n[..., 2] * p[..., 2]
    n /= np.where(ok, np.where(facing > 0, -norm, norm), np.float32(1.0))[..., None]
    return n, ok


def cos_incidence(points: np.ndarray, normals: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """|cos| of the angle between each pixel's viewing ray and the surface normal (1 where the
    normal is unknown, so unknown geometry is not penalised twice)."""
    p = np.asarray(points, np.float32)
    r = np.sqrt(p[..., 0] ** 2 + p[..., 1] ** 2 + p[..., 2] ** 2)
    dot = normals[..., 0] * p[..., 0] + normals[..., 1] * p[..., 1] + normals[..., 2] * p[..., 2]
    c = np.abs(dot) / np.where(r > 0, r, np.float32(1.0))
    return np.where(ok, np.clip(c, 0.0, 1.0), 1.0)


def fuse_pointmap(X_k: np.ndarray, C_k: np.ndarray, X: np.ndarray, C: np.ndarray,
                  mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (2) for every pixel where ``mask`` holds (all if None); returns new ``(X̃, C̃)``.

    ``X_k, X``: (N, 3); ``C_k, C``: (N,) or (N, 1), non-negative. Pixels where both confidences
    are zero keep their old point (nothing to average)."""
    # Weights in float64: a tiny confidence must not lose the point's precision.
    C_k1 = C_k.reshape(-1).astype(np.float64)
    C1 = C.reshape(-1).astype(np.float64)
    if mask is None:
        mask = np.ones(C1.shape, bool)
    C1 = np.where(mask, C1, 0.0)
    total = C_k1 + C1
    safe = np.where(total > 0, total, 1.0)
    X_new = np.where((total > 0)[:, None], (C_k1[:, None] * X_k + C1[:, None] * X) / safe[:, None], X_k)
    return X_new.astype(X_k.dtype, copy=False), total.astype(C_k.dtype, copy=False).reshape(C_k.shape)


def scatter_to_frame(values_k: np.ndarray, idx_f2k: np.ndarray, trusted: np.ndarray, into: np.ndarray) -> np.ndarray:
    """A copy of the frame array ``into`` (H·W or H×W) with ``values_k[ξ]`` written at
    ``idx_f2k[ξ]`` for trusted keyframe pixels ξ (a pixel written twice keeps the later one)."""
    out = into.copy().reshape(-1)
    out[idx_f2k.reshape(-1)[trusted]] = values_k.reshape(-1)[trusted]
    return out.reshape(into.shape)


def fuse(kf: KeyframeFusion, X_in_k: np.ndarray, C: np.ndarray, labels_frame: np.ndarray | None,
         idx_f2k: np.ndarray, valid_match_k: np.ndarray, Qk: np.ndarray, Q_conf: float = Q_CONF) -> np.ndarray:
    """One tracked frame fused into ``kf``: its pointmap expressed in the keyframe frame and matched
    to keyframe pixels (``X_in_k``, ``C`` per keyframe pixel), and its label map through
    ``idx_f2k``. Returns the trusted-match mask."""
    observed, trusted, q = transfer_labels(
        labels_frame if labels_frame is not None else np.zeros(1, np.uint16),
        idx_f2k if labels_frame is not None else np.zeros_like(idx_f2k), valid_match_k, Qk, Q_conf)
    kf.X, kf.C = fuse_pointmap(kf.X, kf.C, X_in_k.reshape(-1, 3).astype(np.float32),
                               C.reshape(-1).astype(np.float32), trusted)
    if labels_frame is not None:
        kf.labels, kf.weights = vote_fuse(kf.labels, kf.weights, observed.astype(np.uint16), q, trusted)
    kf.updates += 1
    return trusted


class NumpyDegrader(Degrader):
    """``Degrader`` with the incidence and depth noise in numpy: the same random draws, in the
    same order."""

    def observe(self, points: np.ndarray, labels: np.ndarray, T_WC: np.ndarray, valid: np.ndarray) -> Observation:
        cfg = self.config
        valid = valid & (points[..., 2] > 0)
        z = np.where(valid, points[..., 2], 0.0).astype(np.float64)
        normals, n_ok = normals_from_pointmap(points, valid)
        cos = cos_incidence(points, normals, n_ok)
        sigma = cfg.sigma(z) / np.maximum(cos, 0.2)
        noise = self.rng.standard_normal(z.shape) * sigma
        scale = np.where(valid, (z + noise) / np.where(z > 0, z, 1.0), 0.0)
        scale = np.maximum(scale, 0.05)  # a point never crosses behind the camera
        noisy = (points * scale[..., None]).astype(np.float32)
        noisy[~valid] = 0.0
        conf = np.where(valid, 1.0 + cfg.c_gain * cos * np.exp(-z / cfg.z_scale), 0.0).astype(np.float32)
        return Observation(noisy, conf, self.degrade_labels(labels, valid), self._drifted(T_WC), valid)


class NumpySimBackend(SimBackend):
    """``SimBackend`` with matching, fusion and the current frame's message in numpy."""

    def __init__(self, config: SimBackendConfig | None = None, labeller=None):
        super().__init__(config, labeller)
        self.degrader = NumpyDegrader(self.config.degradation, self.config.seed)

    def match(self, kf: _Keyframe, truth_points: np.ndarray, truth_valid: np.ndarray, T_WC_true: np.ndarray,
              C_t: np.ndarray) -> Matches:
        h, w = truth_valid.shape
        pc = transform_points(_inv(T_WC_true), kf.world_true)
        z = pc[:, 2]
        front = kf.valid & (z > 1e-6)
        uv, _ = self._camera.project(np.where(front[:, None], pc, [0.0, 0.0, 1.0]))
        u = np.rint(uv[:, 0]).astype(np.int64)
        v = np.rint(uv[:, 1]).astype(np.int64)
        inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        idx = np.where(inside, v * w + u, 0)
        z_here = truth_points.reshape(-1, 3)[idx, 2]
        seen = inside & truth_valid.reshape(-1)[idx]
        tol = self.config.depth_tol_abs + self.config.depth_tol_rel * z
        valid = seen & (np.abs(z_here - z) < tol)
        Qk = np.where(valid, np.sqrt(kf.C0 * C_t.reshape(-1)[idx]), 0.0)
        overlap = float(valid.sum()) / max(1, int(kf.valid.sum()))
        return Matches(idx, valid, Qk, overlap)

    def _fuse(self, kf: _Keyframe, m: Matches, obs: Observation, T_WC_true: np.ndarray) -> None:
        T_KC = _inv(kf.T_WK_true) @ T_WC_true
        X_in_k = transform_points(T_KC, obs.points.reshape(-1, 3)[m.idx_f2k], np.float32)
        fuse(kf.fusion, X_in_k, obs.confidence.reshape(-1)[m.idx_f2k], obs.labels, m.idx_f2k, m.valid_match_k,
             m.Qk, self.config.Q_conf)
        self.last_matches = m

    def _current_frame(self, kf: _Keyframe, obs: Observation, m: Matches,
                       T_WC_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f = kf.fusion
        points = obs.points
        trusted = m.valid_match_k & (m.Qk > self.config.Q_conf)
        labels = scatter_to_frame(f.labels, m.idx_f2k, trusted, obs.labels)
        if self.config.publish == "keyframe":
            T_CK = _inv(T_WC_true) @ kf.T_WK_true
            X = transform_points(T_CK, f.X.reshape(-1, 3)[trusted], np.float32)
            flat = np.array(obs.points, np.float32).reshape(-1, 3)
            flat[m.idx_f2k.reshape(-1)[trusted]] = X
            points = flat.reshape(obs.points.shape)
        return labels, points

