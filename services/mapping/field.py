"""Point queries of the published distance field, for ``map/esdf/query``.

The interpolation is the safety filter's (:class:`riskfield.services.esdf_field.EsdfField`:
trilinear distance, gradient by finite differences through the interpolant, nearest voxel's risk
group), so a client asking the map gets the numbers the filter acts on. What the query service
adds is its outside-the-map rule: a point is *in the map* when it lies inside the grid's voxel
cubes (within half a voxel of the outer centres; z is ignored for a 2-D slice); outside, the
distance is −max_distance when unknown space is occupied and +max_distance otherwise, with a
zero gradient and group 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..esdf_field import EsdfField


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
        groups = [f"group{i}" for i in range(int(self.risk_group.max(initial=0)))]
        self._field = EsdfField(self.distance, self.origin, self.voxel_size, self.risk_group, groups,
                                self.max_distance, self.unknown_is_occupied, check=False)

    @property
    def is_slice(self) -> bool:
        return self.distance.shape[2] == 1

    def query(self, points: np.ndarray) -> FieldAnswer:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n = p.shape[0]
        dims = 2 if self.is_slice else 3
        u = (p[:, :dims] - self.origin[:dims]) / self.voxel_size
        shape = np.asarray(self.distance.shape[:dims])
        in_map = np.all((u >= -0.5) & (u <= shape - 0.5), axis=1)
        outside = -self.max_distance if self.unknown_is_occupied else self.max_distance
        distance = np.full(n, outside, dtype=np.float64)
        gradient = np.zeros((n, 3), dtype=np.float64)
        group = np.zeros(n, dtype=np.uint8)
        if in_map.any():
            s = self._field.query(p[in_map])
            distance[in_map] = s.distance
            gradient[in_map] = s.gradient
            group[in_map] = s.risk_group
        return FieldAnswer(distance, gradient, group, in_map)
