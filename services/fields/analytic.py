"""Closed-form distance fields with the :class:`DistanceField` interface.

An :class:`AnalyticField` is the union of shapes of :mod:`riskfield.services.geometry.shapes`
(planes, boxes, spheres): the distance, gradient, Hessian and risk group (the shape's ``label``)
of the nearest one. Used to test the grid interpolation against exact distance, gradient and
Hessian, to run thousands of closed-loop rollouts quickly, and by simulation benchmarks that
want a geometry-exact field. ``to_esdf`` samples any field onto a grid, which gives an
:class:`EsdfField` (or an ``EsdfGrid`` message) with known ground truth.

Analytic fields are unbounded: every point is inside.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from riskfield.protocol import EsdfGrid

from ..geometry.shapes import Box, Plane, Shape, Sphere
from .base import DistanceField, FieldSample
from .grid import EsdfField


class AnalyticField:
    """The nearest of several shapes: distance, derivatives and group (``label``) of the argmin,

        d(x) = min_i d_i(x),   ∇d(x) = ∇d_k(x),   ∇²d(x) = ∇²d_k(x),   k = argmin_i d_i(x)

    (exact away from the ties where two shapes are equally near). Spheres and planes are
    evaluated together as arrays (this is the hot loop of the rollouts); boxes one by one.
    """

    def __init__(self, shapes: Shape | Sequence[Shape], groups: Sequence[str] = ()):
        self.shapes: list[Shape] = [shapes] if isinstance(shapes, Plane | Box | Sphere) else list(shapes)
        if not self.shapes:
            raise ValueError("an analytic field needs at least one shape")
        self._groups = tuple(groups)
        spheres = [p for p in self.shapes if isinstance(p, Sphere)]
        planes = [p for p in self.shapes if isinstance(p, Plane)]
        self._boxes = [p for p in self.shapes if isinstance(p, Box)]
        self._order: list[Shape] = [*spheres, *planes, *self._boxes]  # index k of the argmin refers to this order
        self._centers = np.array([p.center for p in spheres]).reshape(-1, 3)
        self._radii = np.array([p.radius for p in spheres])
        self._flat = np.array([p.mask for p in spheres]).reshape(-1, 3)
        self._normals = np.array([p.normal for p in planes]).reshape(-1, 3)
        self._offsets = np.array([p.offset for p in planes])
        self._group_of = np.array([p.label for p in self._order], np.int64)
        self._n_spheres = len(spheres)
        self._n_round = len(spheres) + len(planes)

    @property
    def groups(self) -> Sequence[str]:
        return self._groups

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample:
        p = np.asarray(points, np.float64).reshape(-1, 3)
        n = p.shape[0]
        rel = (p[:, None, :] - self._centers[None]) * self._flat[None]  # (N, S, 3)
        rho = np.maximum(np.sqrt((rel * rel).sum(axis=2)), 1e-12)
        parts = [rho - self._radii, p @ self._normals.T - self._offsets]
        parts += [b.distance(p)[:, None] for b in self._boxes]
        d = np.concatenate(parts, axis=1)
        k = np.argmin(d, axis=1)
        rows = np.arange(n)
        grad = np.empty((n, 3))
        hess = np.zeros((n, 3, 3)) if hessian else None
        is_sphere = k < self._n_spheres
        if is_sphere.any():
            ks = k[is_sphere]
            r = rho[is_sphere, ks]
            unit = rel[is_sphere, ks] / r[:, None]
            grad[is_sphere] = unit
            if hess is not None:
                eye = self._flat[ks][:, :, None] * np.eye(3)[None]
                hess[is_sphere] = (eye - unit[:, :, None] * unit[:, None, :]) / r[:, None, None]
        is_plane = ~is_sphere & (k < self._n_round)
        if is_plane.any():
            grad[is_plane] = self._normals[k[is_plane] - self._n_spheres]
        for j, box in enumerate(self._boxes):
            at = k == self._n_round + j
            if at.any():
                grad[at] = box.gradient(p[at])
                if hess is not None:
                    hess[at] = box.hessian(p[at])
        return FieldSample(d[rows, k], grad, hess, self._group_of[k], np.ones(n, bool))


def to_esdf(field: DistanceField, lower: Sequence[float], upper: Sequence[float], voxel_size: float,
            max_distance: float = 2.0, planar: bool = False) -> EsdfField:
    """Sample ``field`` at voxel centres from ``lower`` to ``upper`` (inclusive) into an ESDF.

    ``planar=True`` gives a one-voxel-thick slice at ``lower[2]``.
    """
    lo = np.asarray(lower, np.float64)
    counts = np.floor((np.asarray(upper, np.float64) - lo) / voxel_size + 1e-9).astype(int) + 1
    if planar:
        counts[2] = 1
    axes = [lo[a] + voxel_size * np.arange(counts[a]) for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    s = field.query(grid)
    dist = np.clip(s.distance, -max_distance, max_distance).reshape(counts).astype(np.float32)
    rg = s.risk_group.reshape(counts).astype(np.uint8)
    return EsdfField(dist, lo, voxel_size, rg, field.groups, max_distance)


def to_grid_message(esdf: EsdfField) -> EsdfGrid:
    """The ``EsdfGrid`` message of an :class:`EsdfField`."""
    return EsdfGrid(origin=tuple(esdf.origin), voxel_size=esdf.voxel_size, distance=esdf.distance,
                    risk_group=esdf.risk_groups, groups=list(esdf.groups), max_distance=esdf.max_distance,
                    unknown_is_occupied=esdf.unknown_is_occupied)
