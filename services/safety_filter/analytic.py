"""Closed-form distance fields with the :class:`DistanceField` interface.

Used to test the grid interpolation against exact distance, gradient and Hessian, to run
thousands of closed-loop rollouts quickly, and by simulation benchmarks that want a
geometry-exact field. ``to_esdf`` samples any of them onto a grid, which gives an
:class:`EsdfField` (or an ``EsdfGrid`` message) with known ground truth.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from riskfield.protocol import EsdfGrid

from ..esdf_field import EsdfField, FieldSample


class Plane:
    """Half-space obstacle ``{x : nᵀ(x - point) ≤ 0}``: d = nᵀ(x - point) - margin."""

    def __init__(self, point: Sequence[float], normal: Sequence[float], group: int = 0, margin: float = 0.0,
                 groups: Sequence[str] = ()):
        n = np.asarray(normal, np.float64)
        self.normal = n / np.linalg.norm(n)
        self.point = np.asarray(point, np.float64)
        self.group, self.margin, self._groups = group, margin, tuple(groups)

    @property
    def groups(self) -> Sequence[str]:
        return self._groups

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample:
        p = np.asarray(points, np.float64).reshape(-1, 3)
        n = p.shape[0]
        d = (p - self.point) @ self.normal - self.margin
        grad = np.broadcast_to(self.normal, (n, 3)).copy()
        hess = np.zeros((n, 3, 3)) if hessian else None
        return FieldSample(d, grad, hess, np.full(n, self.group, np.int64), np.ones(n, bool))


class Sphere:
    """Ball obstacle (a disc for a robot in its centre's plane): d = |x - c| - radius - margin.

    With ``planar=True`` it is an infinite vertical cylinder (distance in x, y only).
    """

    def __init__(self, center: Sequence[float], radius: float, group: int = 0, margin: float = 0.0,
                 groups: Sequence[str] = (), planar: bool = False):
        self.center = np.asarray(center, np.float64)
        self.radius, self.group, self.margin, self._groups = radius, group, margin, tuple(groups)
        self.planar = planar

    @property
    def groups(self) -> Sequence[str]:
        return self._groups

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample:
        p = np.asarray(points, np.float64).reshape(-1, 3)
        n = p.shape[0]
        r = p - self.center
        if self.planar:
            r[:, 2] = 0.0
        rho = np.maximum(np.linalg.norm(r, axis=1), 1e-12)
        d = rho - self.radius - self.margin
        unit = r / rho[:, None]
        hess = None
        if hessian:
            eye = np.diag([1.0, 1.0, 0.0]) if self.planar else np.eye(3)
            hess = (eye[None] - unit[:, :, None] * unit[:, None, :]) / rho[:, None, None]
        return FieldSample(d, unit, hess, np.full(n, self.group, np.int64), np.ones(n, bool))


class Box:
    """Axis-aligned solid box with centre c and half extents e, signed distance:

        q = |x - c| - e (per axis),  d = |max(q, 0)| + min(max_i q_i, 0) - margin.

    Outside, the gradient is the unit vector from the nearest surface point and the Hessian
    (P - n nᵀ)/|q₊| with P the projection on the axes where q > 0 (zero on a face's region, a
    cylinder's along an edge, a sphere's at a corner). Inside, the gradient is the normal of the
    nearest face and the Hessian zero. ``planar=True`` extrudes it along z.
    """

    def __init__(self, center: Sequence[float], half: Sequence[float], group: int = 0, margin: float = 0.0,
                 groups: Sequence[str] = (), planar: bool = False):
        self.center = np.asarray(center, np.float64)
        self.half = np.asarray(half, np.float64)
        self.group, self.margin, self._groups, self.planar = group, margin, tuple(groups), planar

    @property
    def groups(self) -> Sequence[str]:
        return self._groups

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample:
        p = np.asarray(points, np.float64).reshape(-1, 3)
        n = p.shape[0]
        rel = p - self.center
        q = np.abs(rel) - self.half
        if self.planar:
            q[:, 2] = -np.inf
        sign = np.where(rel >= 0, 1.0, -1.0)
        pos = np.maximum(q, 0.0)
        out_norm = np.sqrt((pos * pos).sum(axis=1))
        outside = out_norm > 0
        k = np.argmax(q, axis=1)
        d = np.where(outside, out_norm, q[np.arange(n), k]) - self.margin
        grad = np.zeros((n, 3))
        safe = np.maximum(out_norm, 1e-12)[:, None]
        grad[outside] = (sign * pos / safe)[outside]
        ins = ~outside
        grad[ins, k[ins]] = sign[ins, k[ins]]
        hess = None
        if hessian:
            hess = np.zeros((n, 3, 3))
            unit = grad[outside]
            proj = (q[outside] > 0).astype(np.float64)
            hess[outside] = (proj[:, :, None] * np.eye(3)[None] - unit[:, :, None] * unit[:, None, :]) / safe[
                outside][:, :, None]
        return FieldSample(d, grad, hess, np.full(n, self.group, np.int64), np.ones(n, bool))


class Union:
    """The nearest of several obstacles: distance, derivatives and group of the argmin.

    Spheres and planes are evaluated together as arrays (this is the hot loop of the rollouts);
    boxes one by one.
    """

    def __init__(self, parts: Sequence[Plane | Sphere | Box], groups: Sequence[str] = ()):
        self.parts = list(parts)
        self._groups = tuple(groups)
        spheres = [p for p in self.parts if isinstance(p, Sphere)]
        planes = [p for p in self.parts if isinstance(p, Plane)]
        self._boxes = [p for p in self.parts if isinstance(p, Box)]
        self._order = spheres + planes + self._boxes  # index k of the argmin refers to this order
        self._centers = np.array([p.center for p in spheres]).reshape(-1, 3)
        self._radii = np.array([p.radius + p.margin for p in spheres])
        self._flat = np.array([[1.0, 1.0, 0.0] if p.planar else [1.0, 1.0, 1.0] for p in spheres]).reshape(-1, 3)
        self._normals = np.array([p.normal for p in planes]).reshape(-1, 3)
        self._offsets = np.array([p.normal @ p.point + p.margin for p in planes])
        self._group_of = np.array([p.group for p in self._order], np.int64)
        self._n_spheres = len(spheres)

    @property
    def groups(self) -> Sequence[str]:
        return self._groups

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample:
        p = np.asarray(points, np.float64).reshape(-1, 3)
        n = p.shape[0]
        rel = (p[:, None, :] - self._centers[None]) * self._flat[None]  # (N, S, 3)
        rho = np.maximum(np.sqrt((rel * rel).sum(axis=2)), 1e-12)
        box_s = [b.query(p, hessian) for b in self._boxes]
        d = np.concatenate([rho - self._radii, p @ self._normals.T - self._offsets,
                            np.array([b.distance for b in box_s]).reshape(-1, n).T], axis=1)
        k = np.argmin(d, axis=1)
        rows = np.arange(n)
        grad = np.empty((n, 3))
        hess = np.zeros((n, 3, 3)) if hessian else None
        first_box = self._n_spheres + self._normals.shape[0]
        for j, bs in enumerate(box_s):
            won = k == first_box + j
            grad[won] = bs.gradient[won]
            if hess is not None and bs.hessian is not None:
                hess[won] = bs.hessian[won]
        is_sphere = k < self._n_spheres
        if is_sphere.any():
            ks = k[is_sphere]
            r = rho[is_sphere, ks]
            unit = rel[is_sphere, ks] / r[:, None]
            grad[is_sphere] = unit
            if hess is not None:
                eye = self._flat[ks][:, :, None] * np.eye(3)[None]
                hess[is_sphere] = (eye - unit[:, :, None] * unit[:, None, :]) / r[:, None, None]
        is_plane = ~is_sphere & (k < first_box)
        if is_plane.any():
            grad[is_plane] = self._normals[k[is_plane] - self._n_spheres]
        return FieldSample(d[rows, k], grad, hess, self._group_of[k], np.ones(n, bool))


def to_esdf(field: Plane | Sphere | Box | Union, lower: Sequence[float], upper: Sequence[float], voxel_size: float,
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
