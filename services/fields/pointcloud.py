"""The point-cloud baseline: a nearest-point distance barrier over a KD-tree.

The classic perception-based CBF without a map: ``d(p) = ‖p − c(p)‖`` where ``c(p)`` is the
point of the accumulated cloud nearest to ``p``. Away from the cloud it is smooth with

    ∇d = n = (p − c) / ‖p − c‖,      ∇²d = (I − n nᵀ) / ‖p − c‖,

(the distance to a single point), but ``c(p)`` switches between points as the robot moves —
the gradient discontinuities the paper's ESDF is built to avoid. The cloud is unsigned: a
point inside an object is just "close to the surface". Built incrementally from the same
pointmaps as the maps (voxel-downsampled so the tree stays small), it stands in for the
map-based baseline of the paper's equal-time comparison.

scipy (for the KD-tree) is imported when the tree is first built, so ``riskfield.services.fields``
imports with numpy alone (the planner example and a robot-level install need no scipy for the
grid and analytic fields).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .base import FieldSample

if TYPE_CHECKING:
    from scipy.spatial import cKDTree


@dataclass
class PointCloudField:
    """Accumulates world points (voxel-downsampled) and answers nearest-point distances."""

    voxel_size: float = 0.02  # the downsampling cell (m); the filter's map margin reads it as a grid's
    min_distance: float = 1e-4  # keeps n and the Hessian finite exactly on a point
    far: float = 2.0  # distance reported with no points at all (like an ESDF's max_distance)
    curvature: bool = True  # report the point's Hessian; False: the local tangent-plane model (∇²d = 0)
    _keys: set = field(default_factory=set)
    _points: list = field(default_factory=list)
    _tree: cKDTree | None = None

    def integrate(self, points: np.ndarray) -> None:
        """Add world points (N×3), keeping one per voxel."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        p = p[np.isfinite(p).all(axis=1)]
        if p.size == 0:
            return
        keys = np.floor(p / self.voxel_size).astype(np.int64)
        _, first = np.unique(keys, axis=0, return_index=True)
        for k, q in zip(map(tuple, keys[first]), p[first], strict=True):
            if k not in self._keys:
                self._keys.add(k)
                self._points.append(q)
        self._tree = None

    def build(self) -> None:
        """(Re)build the KD-tree over the points gathered so far."""
        if self._points:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(np.asarray(self._points))

    @property
    def size(self) -> int:
        return len(self._points)

    @property
    def groups(self) -> tuple[str, ...]:
        return ()  # geometry only: no risk groups

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample:
        """Nearest-point distance, gradient (and Hessian) at N points — the safety filter's
        ``DistanceField`` protocol, so the same filter runs on it."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        n = p.shape[0]
        if self._tree is None:
            self.build()
        if self._tree is None:  # no points at all: nothing to avoid
            return FieldSample(np.full(n, self.far), np.zeros((n, 3)), np.zeros((n, 3, 3)) if hessian else None,
                               np.zeros(n, np.int64), np.ones(n, bool))
        d, i = self._tree.query(p)
        d = np.maximum(np.asarray(d, dtype=float), self.min_distance)
        normal = (p - self._tree.data[i]) / d[:, None]
        hess = None
        if hessian and not self.curvature:
            hess = np.zeros((n, 3, 3))
        elif hessian:
            hess = (np.eye(3)[None] - normal[:, :, None] * normal[:, None, :]) / d[:, None, None]
        return FieldSample(np.minimum(d, self.far), normal, hess, np.zeros(n, np.int64), np.ones(n, bool))
