"""The interpolated query of an ESDF grid: distance, gradient, Hessian, risk group and the in-map rule.

The ESDF is sampled at voxel centres ``origin + voxel_size * (i, j, k)``. Following the paper
("ESDF gradients and Hessians are computed by finite differences and evaluated at query
points using trilinear interpolation"), a query at a continuous point ``p``:

* distance ``d(p)``: trilinear (bilinear for a 2-D slice) interpolation of the grid;
* gradient: central differences with step ``voxel_size`` taken *through the interpolant*,
  ``(d(p + h e_i) - d(p - h e_i)) / 2h``. Because interpolation is linear along each axis,
  this equals the trilinear interpolation of the grid's central-difference gradient — a
  continuous field (unlike the piecewise-constant exact derivative of the interpolant);
* Hessian: second and mixed differences through the same interpolant (likewise the
  interpolation of the grid's second differences).

All three come from one 4×4×4 (4×4 in 2-D) stencil gathered around the query's cell. Where
the stencil leaves the grid the missing layer is extrapolated linearly, which turns central
differences into one-sided ones at the border instead of halving the gradient.

A 2-D slice (``nz == 1``) is extruded along z: the z coordinate of a query is ignored, the
z-gradient and the z rows of the Hessian are zero.

**The in-map rule** (the one rule of riskfield: ``FieldSample.inside``, the filter's
``outside_map`` brake and the ``in_map`` flag of ``map/esdf/query`` all use it): a point is
*inside* when it lies within the hull of voxel centres, ``origin ≤ p ≤ origin + voxel_size ·
(shape − 1)`` per axis (x and y only for a slice), with a 1e-9 voxel tolerance. That is the
region where the distance is an *interpolation* of stored voxels. In the half voxel beyond the
outer centres (the rest of the outer voxels' cubes) the interpolant has no data on the far side:
a value there would be the border layer clamped or extrapolated — and the 4-point stencil already
has to invent its outer layer for the derivatives at the border. So nothing invented is called map,
and a client is never told "in map" where the filter brakes. Outside points are evaluated at
the nearest point of the hull and flagged; the filter brakes on them and the query service
answers them with the value of unknown space (:func:`answer_query`).

The risk group of a query is the ``risk_group`` of the nearest voxel (the mapper stores there
the group of that voxel's nearest obstacle).

``interpolation`` other than ``trilinear`` (the above) reads the same stencil with a cubic
kernel instead (:func:`kernel_weights`; the kernels and their trade-offs are described in
``riskfield.services.fields.spline``): distance, gradient and Hessian are then the exact
derivatives of one piecewise cubic (the safety filter's default is ``bspline_smooth``).

This module is the one home of the grid query: pure numpy, so the safety filter, the mapping
query service (``riskfield.services.fields``, which adds the scipy prefilter of the
interpolating ``bspline``) and external clients (``riskfield.client``) read a grid the same way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .messages import EsdfGrid


@dataclass(frozen=True)
class FieldSample:
    """Field values at N query points (rows in the order of the query)."""

    distance: np.ndarray  # (N,) metres, signed
    gradient: np.ndarray  # (N, 3)
    hessian: np.ndarray | None  # (N, 3, 3) when asked for
    risk_group: np.ndarray  # (N,) int, 1-based index into the field's groups, 0 = none
    inside: np.ndarray  # (N,) bool: within the field's domain (the in-map rule)


Kernel = Literal["catmull_rom", "bspline", "bspline_smooth"]
KERNELS: tuple[Kernel, ...] = ("catmull_rom", "bspline", "bspline_smooth")

# Weights of the stencil positions (-1, 0, 1, 2) as polynomials in t: w_p(t) = Σ_k M[p, k] t^k.
_CATMULL_ROM = 0.5 * np.array([
    [0.0, -1.0, 2.0, -1.0],
    [2.0, 0.0, -5.0, 3.0],
    [0.0, 1.0, 4.0, -3.0],
    [0.0, 0.0, -1.0, 1.0],
])
_BSPLINE = np.array([
    [1.0, -3.0, 3.0, -1.0],
    [4.0, 0.0, -6.0, 3.0],
    [1.0, 3.0, 3.0, -3.0],
    [0.0, 0.0, 0.0, 1.0],
]) / 6.0
_MATRIX = {"catmull_rom": _CATMULL_ROM, "bspline": _BSPLINE, "bspline_smooth": _BSPLINE}


def kernel_weights(t: np.ndarray, h: float, kernel: Kernel, orders: int) -> np.ndarray:
    """Per-axis stencil weights of the value and its first ``orders - 1`` derivatives.

    ``t`` (N, dims) fractions in the cell; returns (N, dims, orders, 4): row 0 interpolates the
    value, row 1 the first derivative (1/m), row 2 the second (1/m²) — the layout
    :class:`EsdfField` contracts with the stencil.
    """
    m = _MATRIX[kernel]
    t = np.asarray(t, np.float64)
    one, t2 = np.ones_like(t), t * t
    powers = [np.stack([one, t, t2, t2 * t], axis=-1)]  # d⁰/dt⁰ of (1, t, t², t³)
    if orders > 1:
        powers.append(np.stack([0 * t, one, 2 * t, 3 * t2], axis=-1) / h)
    if orders > 2:
        powers.append(np.stack([0 * t, 0 * t, 2 * one, 6 * t], axis=-1) / (h * h))
    return np.stack(powers, axis=-2) @ m.T


Interpolation = Literal["trilinear", "catmull_rom", "bspline", "bspline_smooth"]

_OFFS = np.arange(-1, 3)
_EPS = 1e-9


class EsdfField:
    """A read-only view of one ESDF grid with vectorised interpolated queries.

    ``distance`` (nx, ny, nz) must be finite with nx, ny ≥ 2 (nz = 1 is a 2-D slice);
    ``risk_group`` has the same shape (defaults to all zeros). Arrays are not copied.
    """

    def __init__(
        self,
        distance: np.ndarray,
        origin: Sequence[float],
        voxel_size: float,
        risk_group: np.ndarray | None = None,
        groups: Sequence[str] = (),
        max_distance: float | None = None,
        unknown_is_occupied: bool = False,
        check: bool = True,
        interpolation: Interpolation = "trilinear",
    ):
        dist = np.asarray(distance)
        if dist.ndim != 3:
            raise ValueError(f"distance must be a 3-D array (nz = 1 for a slice), got shape {list(dist.shape)}")
        nx, ny, nz = dist.shape
        if nx < 2 or ny < 2:
            raise ValueError(f"an ESDF needs at least 2 voxels along x and y, got shape {list(dist.shape)}")
        if not (np.isfinite(voxel_size) and voxel_size > 0):
            raise ValueError(f"voxel_size must be positive and finite, got {voxel_size}")
        org = np.asarray(origin, dtype=np.float64).reshape(3)
        if not np.isfinite(org).all():
            raise ValueError("origin must be finite")
        if check and not np.isfinite(dist).all():
            raise ValueError("distance holds NaN or Inf")
        rg = np.zeros(dist.shape, np.uint8) if risk_group is None else np.asarray(risk_group)
        if rg.shape != dist.shape:
            raise ValueError(f"risk_group shape {list(rg.shape)} differs from distance {list(dist.shape)}")
        if check and rg.size and int(rg.max()) > len(groups):
            raise ValueError(f"risk_group id {int(rg.max())} has no entry in groups")
        self.distance = dist
        self.risk_groups = rg
        self.origin = org
        self.voxel_size = float(voxel_size)
        self._groups = tuple(groups)
        self.max_distance = float(max_distance) if max_distance is not None else float(np.abs(dist).max())
        self.unknown_is_occupied = bool(unknown_is_occupied)
        self.planar = nz == 1
        self._dims = 2 if self.planar else 3
        self._shape = np.array(dist.shape[: self._dims])
        self._upper = (self._shape - 1).astype(np.float64)
        self._strides = np.array([ny * nz, nz, 1])[: self._dims]
        self._flat = dist.reshape(-1)
        self._flat_rg = rg.reshape(-1)
        self._origin_d = self.origin[: self._dims].copy()
        self._inv_h = 1.0 / self.voxel_size
        self._upper_eps = self._upper + _EPS
        self._shape_m1, self._shape_m2, self._shape_m3 = self._shape - 1, self._shape - 2, self._shape - 3
        self._w0, self._w1 = axis_weights(self.voxel_size)
        grids = np.meshgrid(*[_OFFS * st for st in self._strides], indexing="ij")
        self._offsets = sum(grids)[None]  # flat offsets of the 4^dims stencil
        # Cubic interpolation (kernel_weights): same stencil, over the kernel's coefficients.
        if interpolation not in ("trilinear", *KERNELS):
            raise ValueError(f"unknown interpolation {interpolation!r}")
        self.interpolation: Interpolation = interpolation
        if interpolation != "trilinear":
            self._flat = self._coefficients(dist, interpolation).reshape(-1)

    @classmethod
    def from_grid(cls, grid: EsdfGrid, interpolation: Interpolation = "trilinear") -> EsdfField:
        """Wrap a decoded ``EsdfGrid`` (zero-copy; the grid's validator already checked it)."""
        return cls(grid.distance, grid.origin, grid.voxel_size, grid.risk_group, grid.groups,
                   grid.max_distance, grid.unknown_is_occupied, check=False, interpolation=interpolation)

    def with_interpolation(self, interpolation: Interpolation) -> EsdfField:
        """The same grid (arrays shared) queried with another interpolation."""
        if interpolation == self.interpolation:
            return self
        return type(self)(self.distance, self.origin, self.voxel_size, self.risk_groups, self._groups,
                          self.max_distance, self.unknown_is_occupied, check=False, interpolation=interpolation)

    def _coefficients(self, distance: np.ndarray, interpolation: Interpolation) -> np.ndarray:
        """The coefficients the cubic kernel is applied to: the samples themselves for Catmull-Rom and
        the smoothing B-spline. The interpolating B-spline needs a global prefilter (scipy), which
        the protocol does not depend on: ``riskfield.services.fields.EsdfField`` adds it."""
        if interpolation == "bspline":
            raise ValueError("the interpolating B-spline needs its prefilter (scipy): use "
                             "riskfield.services.fields.EsdfField, or another interpolation")
        return np.asarray(distance, np.float64)

    @property
    def groups(self) -> Sequence[str]:
        return self._groups

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.distance.shape)  # type: ignore[return-value]

    def upper_corner(self) -> np.ndarray:
        """Centre of the last voxel (the first one's is ``origin``)."""
        return self.origin + self.voxel_size * (np.array(self.distance.shape) - 1)

    def inside(self, points: np.ndarray) -> np.ndarray:
        u = np.asarray(points, np.float64).reshape(-1, 3)[:, : self._dims] - self.origin[: self._dims]
        u /= self.voxel_size
        return ((u >= -_EPS) & (u <= self._upper + _EPS)).all(axis=1)

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n, dims = p.shape[0], self._dims
        u = (p[:, :dims] - self._origin_d) * self._inv_h
        inside = ((u >= -_EPS) & (u <= self._upper_eps)).all(axis=1)
        u = np.minimum(np.maximum(u, 0.0), self._upper)
        i0 = np.minimum(u.astype(np.int64), self._shape_m2)  # u ≥ 0, so truncation is floor
        t = u - i0
        block = self._stencil(i0)  # (N, 4, 4[, 4])
        # Every output is a linear functional of the stencil: contract it axis by axis with the
        # 1-D weights of (value, first, second) difference, interpolated at the fraction t.
        k = 3 if hessian else 2
        if self.interpolation == "trilinear":
            w = self._w0[:k] + t[:, :, None, None] * self._w1[:k]  # (N, dims, k, 4)
        else:
            w = kernel_weights(t, self.voxel_size, self.interpolation, k)
        hess = None
        if dims == 2:
            r = w[:, 0] @ block @ np.swapaxes(w[:, 1], 1, 2)  # (N, kx, ky)
            grad = np.zeros((n, 3))
            grad[:, :2] = r[:, _G2[0], _G2[1]]
            if hessian:
                hess = np.zeros((n, 3, 3))
                hess[:, :2, :2] = r[:, _H2[0], _H2[1]]
            dist = r[:, 0, 0]
        else:
            r = block @ np.swapaxes(w[:, 2], 1, 2)[:, None]  # (N, 4x, 4y, kz)
            r = w[:, 1][:, None] @ r  # (N, 4x, ky, kz)
            r = (w[:, 0].reshape(n, k, 4) @ r.reshape(n, 4, k * k)).reshape(n, k, k, k)
            grad = r[:, _G3[0], _G3[1], _G3[2]]
            if hessian:
                hess = r[:, _H3[0], _H3[1], _H3[2]]
            dist = r[:, 0, 0, 0]
        nearest = np.minimum((u + 0.5).astype(np.int64), self._shape_m1)
        rg = self._flat_rg[nearest @ self._strides].astype(np.int64)
        return FieldSample(dist, grad, hess, rg, inside)

    def _stencil(self, i0: np.ndarray) -> np.ndarray:
        """The 4^dims voxels around each query's cell as float64, linearly extrapolated past the border."""
        flat = (i0 @ self._strides).reshape((-1,) + (1,) * self._dims) + self._offsets
        if (i0 >= 1).all() and (i0 <= self._shape_m3).all():
            return self._flat[flat].astype(np.float64)
        # Near the border: clamp the stencil, then replace clamped layers by linear extrapolation.
        dims = self._dims
        idx = [np.clip(i0[:, a, None] + _OFFS, 0, self._shape[a] - 1) * self._strides[a] for a in range(dims)]
        if dims == 2:
            flat = idx[0][:, :, None] + idx[1][:, None, :]
        else:
            flat = idx[0][:, :, None, None] + idx[1][:, None, :, None] + idx[2][:, None, None, :]
        block = self._flat[flat].astype(np.float64)
        for a in range(dims):
            lo = i0[:, a] == 0
            hi = i0[:, a] + 2 > self._shape[a] - 1
            b = np.moveaxis(block, a + 1, 1)  # a view: writes go to block
            b[lo, 0] = 2 * b[lo, 1] - b[lo, 2]
            b[hi, 3] = 2 * b[hi, 2] - b[hi, 1]
        return block


# Where the partial derivatives sit in the contracted tensor r[x-order, y-order(, z-order)].
_G2 = np.array([[1, 0], [0, 1]])
_H2 = np.array([[[2, 1], [1, 0]], [[0, 1], [1, 2]]])
_G3 = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]])
_H3 = np.array([
    [[2, 1, 1], [1, 0, 0], [1, 0, 0]],
    [[0, 1, 0], [1, 2, 1], [0, 1, 0]],
    [[0, 0, 1], [0, 0, 1], [1, 1, 2]],
])


def axis_weights(h: float) -> tuple[np.ndarray, np.ndarray]:
    """Weights over the stencil positions (-1, 0, 1, 2) of one axis, affine in the fraction t.

    Row 0 interpolates the value between positions 0 and 1 at fraction t; row 1 interpolates
    the central difference (f[i+1] - f[i-1]) / 2h; row 2 the second difference
    (f[i+1] - 2 f[i] + f[i-1]) / h². Tensor products of rows give every partial derivative
    (the mixed central difference is the product of two first differences). Returns
    (W0, W1) with weights W0 + t * W1, each (3, 4).
    """
    w0 = np.array([[0.0, 1.0, 0.0, 0.0], [-1.0 / (2 * h), 0.0, 1.0 / (2 * h), 0.0], [1.0, -2.0, 1.0, 0.0]])
    w1 = np.array([
        [0.0, -1.0, 1.0, 0.0],
        [1.0 / (2 * h), -1.0 / (2 * h), -1.0 / (2 * h), 1.0 / (2 * h)],
        [-1.0, 3.0, -3.0, 1.0],
    ])
    w0[2] /= h * h
    w1[2] /= h * h
    return w0, w1


def unknown_sample(n: int, max_distance: float, unknown_is_occupied: bool) -> FieldSample:
    """What the query service answers outside the map (or before the first map): the distance of
    unknown space (−max_distance when it counts as occupied, +max_distance otherwise), a zero
    gradient, no risk group, ``inside`` False."""
    d = -max_distance if unknown_is_occupied else max_distance
    return FieldSample(np.full(n, float(d)), np.zeros((n, 3)), None, np.zeros(n, np.int64), np.zeros(n, bool))


def answer_query(field: EsdfField, points: np.ndarray) -> FieldSample:
    """A ``map/esdf/query`` answer: :meth:`EsdfField.query` where the point is inside (the in-map
    rule above), :func:`unknown_sample` elsewhere — so a client is told
    "in map" exactly where the filter acts on the field and is not braking with ``outside_map``."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    s = field.query(p)
    out = unknown_sample(p.shape[0], field.max_distance, field.unknown_is_occupied)
    k = s.inside
    out.distance[k] = s.distance[k]
    out.gradient[k] = s.gradient[k]
    out.risk_group[k] = s.risk_group[k]
    out.inside[k] = True
    return out


__all__ = ["KERNELS", "EsdfField", "FieldSample", "Interpolation", "Kernel", "answer_query", "axis_weights",
           "kernel_weights", "unknown_sample"]
