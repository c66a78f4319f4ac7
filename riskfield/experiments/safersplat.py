"""A SaferSplat-*style* baseline: anisotropic Gaussians fitted to the observed points and
SaferSplat's ellipsoid-distance CBF over them. Not SaferSplat itself (no photometric 3DGS
training, no rendering): what it shares with SaferSplat is the map's form (full-covariance
Gaussians) and the barrier (squared distance from the robot to each Gaussian's ellipsoid).

**Map** (:func:`fit_gaussians`). Per-cluster covariances: the world points of every frame (the same
confidence-filtered points each method gets) are binned into cubic cells of ``cell`` metres; each
cell keeps its point count, sum and sum of outer products, so a frame costs one pass. At the end each
cell with at least ``min_points`` points becomes a Gaussian: mean μ, covariance Σ = RΛRᵀ. Its
ellipsoid has semi-axes ``s = √3·√λ`` (a uniform spread over [−a, a] has σ = a/√3, so the ellipsoid
spans the cell's points), floored at ``min_axis``. Frames are consumed until the time spent reaches
the budget (the ESDF pipeline's reconstruction wall time in the same run).

**Barrier** (:class:`EllipsoidBarrier`). As SaferSplat's ``splat/distances.py``
(``distance_point_ellipsoid``): the robot sphere of radius r against ellipsoid i is the point
against the ellipsoid grown by r (``s + r``, an approximation of the Minkowski sum); in its frame
q = Rᵀ(p − μ), the closest point is ``y = s²q / (s² + λ)`` with λ ≥ 0 the root of
``Σ s_j²q_j² / (s_j² + λ)² = 1`` (Newton from λ = 0, monotone since the left side is convex and
decreasing), and

    h = ‖q − y‖²,   ∇h = 2(q − y),   ∇²h = 2(I − ∂y/∂q),
    ∂y/∂q = diag(s²/(s²+λ)) − (s²q/(s²+λ)²) (∂λ/∂q)ᵀ,   ∂λ/∂q_j = (s_j²q_j/(s_j²+λ)²) / Σ s_i²q_i²/(s_i²+λ)³

(rotated back to the world by R). Inside an ellipsoid (a collision) h = (‖q/s‖² − 1)·min(s)², which
is continuous with the outside at the surface. SaferSplat puts every Gaussian's row in the QP and
prunes redundant ones (a minimal polytope); here the ``k`` Gaussians with the nearest means carry a
row each, which keeps the per-step work bounded on this CPU.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

SQRT3 = math.sqrt(3.0)


@dataclass
class GaussianMap:
    """Gaussians as ellipsoids: means (N, 3), rotations R (N, 3, 3, columns = axes), semi-axes (N, 3)."""

    means: np.ndarray
    rotations: np.ndarray
    axes: np.ndarray
    frames: int = 0
    build_s: float = 0.0

    def __post_init__(self) -> None:
        self.tree = cKDTree(self.means) if len(self.means) else None

    def __len__(self) -> int:
        return len(self.means)


def cell_moments(points: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per occupied cell: integer key (M, 3), count (M,), Σx (M, 3), Σxxᵀ (M, 3, 3)."""
    keys = np.floor(points / cell).astype(np.int64)
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    m = len(uniq)
    count = np.bincount(inv, minlength=m).astype(np.float64)
    s1 = np.stack([np.bincount(inv, points[:, j], m) for j in range(3)], axis=1)
    s2 = np.empty((m, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            s2[:, i, j] = s2[:, j, i] = np.bincount(inv, points[:, i] * points[:, j], m)
    return uniq, count, s1, s2


def gaussians_from_moments(keys: np.ndarray, count: np.ndarray, s1: np.ndarray, s2: np.ndarray,
                           min_points: int, min_axis: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge moments of equal keys, then one Gaussian (mean, rotation, semi-axes) per cell."""
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    m = len(uniq)
    n = np.bincount(inv, count, m)
    a1 = np.stack([np.bincount(inv, s1[:, j], m) for j in range(3)], axis=1)
    a2 = np.stack([np.stack([np.bincount(inv, s2[:, i, j], m) for j in range(3)], axis=1) for i in range(3)],
                  axis=1)
    ok = n >= min_points
    n, a1, a2 = n[ok], a1[ok], a2[ok]
    mean = a1 / n[:, None]
    cov = a2 / n[:, None, None] - np.einsum("ni,nj->nij", mean, mean)
    lam, rot = np.linalg.eigh(cov)
    axes = np.maximum(SQRT3 * np.sqrt(np.clip(lam, 0.0, None)), min_axis)
    return mean, rot, axes


def fit_gaussians(frames: Sequence, budget_s: float, cell: float = 0.1, min_points: int = 6,
                  min_axis: float = 0.01) -> GaussianMap:
    """Gaussians from the frames' world points, consuming frames until ``budget_s`` is spent."""
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    spent, used = 0.0, 0
    for f in frames:
        if spent >= budget_s:
            break
        t0 = time.perf_counter()
        w = f.world_points()
        if len(w):
            parts.append(cell_moments(w, cell))
        spent += time.perf_counter() - t0
        used += 1
    t0 = time.perf_counter()
    if parts:
        keys, count, s1, s2 = (np.concatenate([p[i] for p in parts]) for i in range(4))
        mean, rot, axes = gaussians_from_moments(keys, count, s1, s2, min_points, min_axis)
    else:
        mean, rot, axes = np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3))
    spent += time.perf_counter() - t0
    return GaussianMap(mean, rot, axes, used, spent)


def ellipsoid_sq_distance(q: np.ndarray, s: np.ndarray, iters: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Squared distance from local points q (m, 3) to axis-aligned ellipsoids with semi-axes s (m, 3),
    its gradient and Hessian in the local frame (see the module docstring); negative inside."""
    s2 = s * s
    z2 = np.sum(q * q / s2, axis=1)
    inside = z2 < 1.0
    lam = np.zeros(len(q))
    sq2 = s2 * q * q
    for _ in range(iters):
        den = s2 + lam[:, None]
        f = np.sum(sq2 / den**2, axis=1) - 1.0
        df = -2.0 * np.sum(sq2 / den**3, axis=1)
        step = np.where(inside, 0.0, f / np.where(df < 0, df, -1.0))
        lam = lam - step
        if np.all(np.abs(step) < 1e-12 * (1.0 + lam)):
            break
    den = s2 + lam[:, None]
    y = s2 * q / den
    diff = q - y
    h = np.sum(diff * diff, axis=1)
    grad = 2.0 * diff
    dy_dlam = -s2 * q / den**2  # ∂y/∂λ
    dF_dlam = -2.0 * np.sum(sq2 / den**3, axis=1)
    dF_dq = 2.0 * s2 * q / den**2
    with np.errstate(divide="ignore", invalid="ignore"):
        dlam_dq = np.where(dF_dlam[:, None] < 0, -dF_dq / dF_dlam[:, None], 0.0)
    dy_dq = np.einsum("mi,ij->mij", s2 / den, np.eye(3)) + np.einsum("mi,mj->mij", dy_dlam, dlam_dq)
    hess = 2.0 * (np.eye(3)[None] - dy_dq)
    if inside.any():
        smin2 = np.min(s2[inside], axis=1)
        h[inside] = (z2[inside] - 1.0) * smin2
        grad[inside] = 2.0 * q[inside] / s2[inside] * smin2[:, None]
        hess[inside] = 2.0 * np.einsum("mi,ij->mij", smin2[:, None] / s2[inside], np.eye(3))
    return h, grad, hess


class EllipsoidBarrier:
    """SaferSplat's ellipsoid-distance barrier rows for the ``k`` Gaussians nearest the robot."""

    def __init__(self, gmap: GaussianMap, radius: float, k: int = 12):
        self.gmap, self.radius, self.k = gmap, radius, min(k, len(gmap))
        if self.k == 0:
            raise ValueError("the Gaussian map is empty")
        self.grown = gmap.axes + radius

    def __call__(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        _, idx = self.gmap.tree.query(p, k=self.k)
        idx = np.atleast_1d(idx)
        rot = self.gmap.rotations[idx]
        q = np.einsum("mji,mj->mi", rot, p[None] - self.gmap.means[idx])  # Rᵀ(p − μ)
        h, g, hess = ellipsoid_sq_distance(q, self.grown[idx])
        g_w = np.einsum("mij,mj->mi", rot, g)
        hess_w = np.einsum("mij,mjk,mlk->mil", rot, hess, rot)
        return h, g_w, hess_w
