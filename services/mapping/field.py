"""Point queries of a published distance field: distance, gradient and risk group.

Same convention as ``EsdfGrid``: ``distance[i, j, k]`` is the value at the centre of voxel
(i, j, k), at ``origin + voxel_size · (i, j, k)``. Following the paper ("gradients computed
by finite differences and evaluated at query points using trilinear interpolation"), the
gradient grid is the central-difference gradient of the distance grid (one-sided at the
edges) and both are interpolated trilinearly at the query points; a 2-D slice (nz = 1) is
interpolated bilinearly in x, y with a zero z-gradient, whatever the query's z. The risk
group is the nearest voxel's.

A point is *in the map* when it lies inside the grid's voxel cubes (within half a voxel of
the outer centres; z is ignored for a slice). Outside, the distance is −max_distance when
unknown space is occupied and +max_distance otherwise, with a zero gradient and group 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FieldAnswer:
    distance: np.ndarray  # (N,) float64
    gradient: np.ndarray  # (N, 3) float64
    risk_group: np.ndarray  # (N,) uint8
    in_map: np.ndarray  # (N,) bool


class DistanceField:
    """A read-only view of one ESDF grid that answers point queries."""

    def __init__(self, distance: np.ndarray, risk_group: np.ndarray, origin: np.ndarray, voxel_size: float,
                 max_distance: float, unknown_is_occupied: bool):
        self.distance = np.asarray(distance, dtype=np.float32)
        self.risk_group = np.asarray(risk_group, dtype=np.uint8)
        self.origin = np.asarray(origin, dtype=np.float64)
        self.voxel_size = float(voxel_size)
        self.max_distance = float(max_distance)
        self.unknown_is_occupied = bool(unknown_is_occupied)
        self._gradient: np.ndarray | None = None

    @property
    def is_slice(self) -> bool:
        return self.distance.shape[2] == 1

    @property
    def gradient_grid(self) -> np.ndarray:
        """(nx, ny, nz, 3) finite-difference gradient, computed once on first use."""
        if self._gradient is None:
            d = self.distance.astype(np.float64)
            g = np.zeros((*d.shape, 3), dtype=np.float32)
            for a in range(2 if self.is_slice else 3):
                if d.shape[a] > 1:
                    g[..., a] = np.gradient(d, self.voxel_size, axis=a)
            self._gradient = g
        return self._gradient

    def query(self, points: np.ndarray) -> FieldAnswer:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n = p.shape[0]
        shape = np.asarray(self.distance.shape)
        u = (p - self.origin) / self.voxel_size
        dims = 2 if self.is_slice else 3
        if self.is_slice:
            u[:, 2] = 0.0
        in_map = np.all((u[:, :dims] >= -0.5) & (u[:, :dims] <= shape[:dims] - 0.5), axis=1)
        outside = -self.max_distance if self.unknown_is_occupied else self.max_distance
        distance = np.full(n, outside, dtype=np.float64)
        gradient = np.zeros((n, 3), dtype=np.float64)
        group = np.zeros(n, dtype=np.uint8)
        if in_map.any():
            ui = u[in_map]
            i0, f = self._cell(ui, shape)
            distance[in_map] = self._interp(self.distance, i0, f)
            grad = self.gradient_grid
            for a in range(dims):
                gradient[in_map, a] = self._interp(grad[..., a], i0, f)
            nearest = np.clip(np.floor(ui + 0.5).astype(np.int64), 0, shape - 1)
            group[in_map] = self.risk_group[nearest[:, 0], nearest[:, 1], nearest[:, 2]]
        return FieldAnswer(distance, gradient, group, in_map)

    @staticmethod
    def _cell(u: np.ndarray, shape: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lower corner and fractions of the interpolation cell; clamped (constant beyond the centres)."""
        hi = np.maximum(shape - 2, 0)
        i0 = np.clip(np.floor(u).astype(np.int64), 0, hi)
        f = np.clip(u - i0, 0.0, 1.0)
        f[:, shape == 1] = 0.0
        return i0, f

    @staticmethod
    def _interp(grid: np.ndarray, i0: np.ndarray, f: np.ndarray) -> np.ndarray:
        shape = np.asarray(grid.shape)
        i1 = np.minimum(i0 + 1, shape - 1)
        out = np.zeros(i0.shape[0], dtype=np.float64)
        for cx in (0, 1):
            ix = i1[:, 0] if cx else i0[:, 0]
            wx = f[:, 0] if cx else 1.0 - f[:, 0]
            for cy in (0, 1):
                iy = i1[:, 1] if cy else i0[:, 1]
                wy = f[:, 1] if cy else 1.0 - f[:, 1]
                for cz in (0, 1):
                    iz = i1[:, 2] if cz else i0[:, 2]
                    wz = f[:, 2] if cz else 1.0 - f[:, 2]
                    out += wx * wy * wz * grid[ix, iy, iz]
        return out
