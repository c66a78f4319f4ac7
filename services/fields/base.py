"""The field interface every consumer programs against: :class:`DistanceField` and :class:`FieldSample`.

A distance field answers, at N world points, the signed distance ``d`` to the nearest obstacle
(negative inside), its gradient ``∇d`` and optionally its Hessian ``∇²d``, the risk group of that
obstacle, and whether the point is *inside* the field's domain. Implementations: the ESDF grid
(:class:`~riskfield.services.fields.grid.EsdfField`), closed-form shapes
(:class:`~riskfield.services.fields.analytic.AnalyticField`) and the point-cloud baseline
(:class:`~riskfield.services.fields.pointcloud.PointCloudField`); the latter two are unbounded,
so every point is inside.

The in-map rule (one rule, used by ``FieldSample.inside``, the safety filter's ``outside_map``
brake and the ``in_map`` flag of the mapping query service) is stated in
:mod:`riskfield.protocol.field`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

# One home with the grid query it comes from (external clients read grids without the services).
from riskfield.protocol.field import FieldSample


class DistanceField(Protocol):
    """What the filter, the query service and the benchmarks need of a field."""

    @property
    def groups(self) -> Sequence[str]: ...

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample: ...


__all__ = ["DistanceField", "FieldSample"]
