"""One field API: every distance field the safety filter, the mapping query service, the
experiments and the benchmarks use.

    base        DistanceField (the interface), FieldSample (what a query returns)
    grid        EsdfField: a published ESDF grid, interpolated; the in-map rule; answer_query
                (what ``map/esdf/query`` answers)
    analytic    AnalyticField: unions of closed-form shapes (``geometry.shapes``); to_esdf
    pointcloud  PointCloudField: the nearest-point baseline over a KD-tree (scipy, imported lazily)

numpy only at import time (numba where installed, for the grid query): a robot-level install (and the
planner example) can use it.
"""

from .analytic import AnalyticField, to_esdf, to_grid_message
from .base import DistanceField, FieldSample
from .grid import EsdfField, answer_query, unknown_sample
from .pointcloud import PointCloudField

__all__ = [
    "AnalyticField",
    "DistanceField",
    "EsdfField",
    "FieldSample",
    "PointCloudField",
    "answer_query",
    "to_esdf",
    "to_grid_message",
    "unknown_sample",
]
