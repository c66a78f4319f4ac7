"""The ESDF grid field: a published ``EsdfGrid`` read by the safety filter, the mapping service's
queries and the benchmarks: distance, gradient, Hessian and risk group.

The query itself (the stencil, trilinear finite differences or a cubic kernel, the linear
extrapolation past the border, the nearest-voxel risk group) and **the in-map rule** live in
:mod:`riskfield.protocol.field` (compiled where numba is installed), so that external clients
(``riskfield.client``) read a grid exactly as the filter does. This :class:`EsdfField` adds the
interpolating ``bspline``, whose global prefilter needs scipy (``fields.spline``).
"""

from __future__ import annotations

import numpy as np

from riskfield.protocol import field as _field
from riskfield.protocol.field import Interpolation, answer_query, axis_weights, unknown_sample

from . import spline as field_spline
from .base import DistanceField, FieldSample


class EsdfField(_field.EsdfField):
    """The protocol's ``EsdfField`` with every interpolation: it adds the interpolating B-spline's
    prefilter (scipy)."""

    def _coefficients(self, distance: np.ndarray, interpolation: Interpolation) -> np.ndarray:
        return field_spline.prefilter(distance, interpolation, self.planar)


__all__ = ["DistanceField", "EsdfField", "FieldSample", "Interpolation", "answer_query", "axis_weights",
           "unknown_sample"]
