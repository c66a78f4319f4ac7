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
kernel instead (the kernels and their trade-offs are described in
``riskfield.services.fields.spline``): distance, gradient and Hessian are then the exact
derivatives of one piecewise cubic (the safety filter's default is ``bspline_smooth``).

This module is the one home of the grid query, :func:`query_point`: the safety filter's compiled
step calls it per barrier point, :meth:`EsdfField.query` over an array of points, and so the
mapping query service (``riskfield.services.fields``, which adds the scipy prefilter of the
interpolating ``bspline``) and external clients (``riskfield.client``) read a grid exactly as the
filter does. It is compiled where numba is installed (``protocol.kernels.jit``) and runs
interpreted, the same code, where it is not (a client without numba: ~0.1 ms a point on a slice,
~0.2 ms in 3-D, instead of well under a microsecond).

Each axis' stencil weights are polynomials in the cell fraction t, w[o, p](t) = Σ_q P[o, p, q] t^q,
for the value (o = 0), first (o = 1) and second (o = 2) derivative at stencil position p: the
trilinear finite-difference weights (:func:`axis_weights`) and the cubic kernels (:data:`_MATRIX`)
both take this form (:func:`stencil_polynomials`), so one contraction serves all four
interpolations.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .kernels import Layout, jit, view1, view3
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


Interpolation = Literal["trilinear", "catmull_rom", "bspline", "bspline_smooth"]

_EPS = 1e-9


class EsdfField:
    """A read-only view of one ESDF grid with interpolated queries over arrays of points.

    ``distance`` (nx, ny, nz) must be finite with nx, ny ≥ 2 (nz = 1 is a 2-D slice);
    ``risk_group`` has the same shape (defaults to all zeros). Arrays are not copied, but the
    query reads them as :func:`kernel_view` has them at the first query (a float32 or read-only
    grid converted once): a changed grid is a new field.
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
        self._flat = dist.reshape(-1)
        self._kernel: tuple | None = None  # kernel_view(self), built at the first query
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
        """The in-map rule (the module's docstring) at each point."""
        return self.query(points).inside

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample:
        """:func:`query_point` at each of the N points (N × 3): the Hessian only when asked for."""
        # numba compiles per argument type and a read-only array is another type: a decoded
        # message's points are copied rather than compiled for.
        p = np.require(np.asarray(points, dtype=np.float64).reshape(-1, 3), requirements=("C", "W"))
        n = p.shape[0]
        out = (np.empty(n), np.empty((n, 3)), np.empty((n, 3, 3)), np.empty(n, np.int64), np.empty(n, np.bool_))
        query_points(kernel_view(self), 3 if hessian else 2, p, out, np.empty(QUERY_SCRATCH_SIZE))
        dist, grad, hess, rg, inside = out
        return FieldSample(dist, grad, hess if hessian else None, rg, inside)


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


def stencil_polynomials(interpolation: Interpolation, h: float) -> np.ndarray:
    """P (3, 4, 4): per-axis weights w[o, p](t) = Σ_q P[o, p, q] t^q of an interpolation on voxels of
    size h (the module's docstring)."""
    poly = np.zeros((3, 4, 4))
    if interpolation == "trilinear":
        w0, w1 = axis_weights(h)
        poly[:, :, 0], poly[:, :, 1] = w0, w1
        return poly
    m = _MATRIX[interpolation]  # w_p(t) = Σ_k M[p, k] t^k
    for q in range(4):
        poly[0, :, q] = m[:, q]
        if q >= 1:
            poly[1, :, q - 1] = m[:, q] * q / h
        if q >= 2:
            poly[2, :, q - 2] = m[:, q] * q * (q - 1) / (h * h)
    return poly


#: The field's metadata as :func:`query_point` reads it (:func:`kernel_view`).
FIELD_INTS = Layout("FieldInts", [("dims", (1,)), ("shape", (3,)), ("strides", (3,))])
FIELD_FLOATS = Layout("FieldFloats", [("origin", (3,)), ("inv_h", (1,)), ("poly", (3, 4, 4))])
_FI, _FF = FIELD_INTS.table(), FIELD_FLOATS.table()
_FIS, _FFS = FIELD_INTS.slot, FIELD_FLOATS.slot


def kernel_view(field: EsdfField) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(coefficients float64, risk groups uint8, metadata int64 (:data:`FIELD_INTS`), metadata
    float64 (:data:`FIELD_FLOATS`)): ``field`` as :func:`query_point` reads it, built once per field.

    numba compiles per argument type, so one contiguous, writeable float64 and uint8 array serve
    every map (a message's float32 or read-only arrays are converted here, once); and a call into
    numba costs per argument, so the metadata travels as two small tables."""
    if field._kernel is not None:
        return field._kernel
    flat = field._flat
    if flat.dtype != np.float64 or not flat.flags.writeable or not flat.flags.c_contiguous:
        flat = np.array(flat, np.float64)
    rgs = field.risk_groups.reshape(-1)
    if rgs.dtype != np.uint8 or not rgs.flags.writeable or not rgs.flags.c_contiguous:
        rgs = np.array(rgs, np.uint8)
    nx, ny, nz = field.distance.shape
    dims = 2 if field.planar else 3
    meta_i = np.zeros(Layout.size(_FI), np.int64)
    FIELD_INTS.view(meta_i, _FI, "dims")[0] = dims
    FIELD_INTS.view(meta_i, _FI, "shape")[:] = (nx, ny, nz)
    FIELD_INTS.view(meta_i, _FI, "strides")[:] = (ny * nz, nz, 1)
    meta_f = np.zeros(Layout.size(_FF))
    FIELD_FLOATS.view(meta_f, _FF, "origin")[:] = field.origin
    FIELD_FLOATS.view(meta_f, _FF, "inv_h")[0] = 1.0 / field.voxel_size
    FIELD_FLOATS.view(meta_f, _FF, "poly")[:] = stencil_polynomials(field.interpolation, field.voxel_size)
    field._kernel = (flat, rgs, meta_i, meta_f)
    return field._kernel


#: The scratch of one :func:`query_point`: the stencil's values, its per-axis weights and the
#: partial contractions.
QUERY_SCRATCH = Layout("QueryScratch", [("block", (4, 4, 4)), ("w", (3, 3, 4)), ("r1", (4, 4, 3)),
                                        ("r2", (4, 3, 3)), ("r3", (3, 3, 3))])
_QS = QUERY_SCRATCH.table()
_QSS = QUERY_SCRATCH.slot
#: Floats a caller keeps for :func:`query_point`'s ``scratch``.
QUERY_SCRATCH_SIZE = Layout.size(_QS)


@jit
def query_point(field, k, p, i, out, scratch):
    """The field at one point p, into row i of ``out`` = (distance, gradient, Hessian when k = 3,
    risk group, inside). ``field`` is the tuple :func:`kernel_view` gives; ``scratch`` holds
    :data:`QUERY_SCRATCH_SIZE` floats."""
    flat, rgs, meta_i, meta_f = field
    dist, grad, hess, rg_out, inside = out
    dims, shape, strides = view1(meta_i, _FI, _FIS.dims)[0], view1(meta_i, _FI, _FIS.shape), \
        view1(meta_i, _FI, _FIS.strides)
    origin, inv_h, poly = view1(meta_f, _FF, _FFS.origin), view1(meta_f, _FF, _FFS.inv_h)[0], \
        view3(meta_f, _FF, _FFS.poly)
    block, w, r1 = view3(scratch, _QS, _QSS.block), view3(scratch, _QS, _QSS.w), view3(scratch, _QS, _QSS.r1)
    r2, r3 = view3(scratch, _QS, _QSS.r2), view3(scratch, _QS, _QSS.r3)
    ins = True
    ix0 = iy0 = iz0 = 0
    nx = ny = nz = 0
    for a in range(dims):
        u = (p[a] - origin[a]) * inv_h
        upper = shape[a] - 1.0
        if not (u >= -_EPS and u <= upper + _EPS):
            ins = False
        u = min(max(u, 0.0), upper)
        c = min(int(u), shape[a] - 2)
        t = u - c
        near = min(int(u + 0.5), shape[a] - 1)
        if a == 0:
            ix0 = c
            nx = near
        elif a == 1:
            iy0 = c
            ny = near
        else:
            iz0 = c
            nz = near
        t2 = t * t
        t3 = t2 * t
        for o in range(k):
            for q in range(4):
                w[a, o, q] = poly[o, q, 0] + poly[o, q, 1] * t + poly[o, q, 2] * t2 + poly[o, q, 3] * t3
    inside[i] = ins
    rg_out[i] = rgs[nx * strides[0] + ny * strides[1] + nz * strides[2]]  # nz = 0 on a slice
    # The 4^dims stencil, clamped to the grid, then clamped layers replaced by linear extrapolation.
    # A slice is one z layer, read with the value's weight 1 alone: it is extruded along z.
    nzs, kz = (4, k) if dims == 3 else (1, 1)
    if dims == 2:
        w[2, 0, 0] = 1.0
    for a in range(4):
        xa = min(max(ix0 - 1 + a, 0), shape[0] - 1) * strides[0]
        for b in range(4):
            yb = min(max(iy0 - 1 + b, 0), shape[1] - 1) * strides[1]
            for c in range(nzs):
                block[a, b, c] = flat[xa + yb + min(max(iz0 - 1 + c, 0), shape[2] - 1) * strides[2]]
    starts = (ix0, iy0, iz0)
    for ax in range(dims):
        lo = starts[ax] == 0
        hi = starts[ax] + 2 > shape[ax] - 1
        if not (lo or hi):
            continue
        for e in range(4):
            for f in range(nzs if ax != 2 else 4):
                if ax == 0:
                    if lo:
                        block[0, e, f] = 2 * block[1, e, f] - block[2, e, f]
                    if hi:
                        block[3, e, f] = 2 * block[2, e, f] - block[1, e, f]
                elif ax == 1:
                    if lo:
                        block[e, 0, f] = 2 * block[e, 1, f] - block[e, 2, f]
                    if hi:
                        block[e, 3, f] = 2 * block[e, 2, f] - block[e, 1, f]
                else:
                    if lo:
                        block[e, f, 0] = 2 * block[e, f, 1] - block[e, f, 2]
                    if hi:
                        block[e, f, 3] = 2 * block[e, f, 2] - block[e, f, 1]
    # r[ox, oy, oz] = Σ_abc wx[ox, a] wy[oy, b] wz[oz, c] block[a, b, c]: contract z, then y, then x.
    for a in range(4):
        for b in range(4):
            for oz in range(kz):
                s = 0.0
                for c in range(nzs):
                    s += block[a, b, c] * w[2, oz, c]
                r1[a, b, oz] = s
    for a in range(4):
        for oy in range(k):
            for oz in range(kz):
                s = 0.0
                for b in range(4):
                    s += w[1, oy, b] * r1[a, b, oz]
                r2[a, oy, oz] = s
    for ox in range(k):
        for oy in range(k):
            for oz in range(kz):
                s = 0.0
                for a in range(4):
                    s += w[0, ox, a] * r2[a, oy, oz]
                r3[ox, oy, oz] = s
    for a in range(3):
        grad[i, a] = 0.0
        for b in range(3):
            hess[i, a, b] = 0.0
    dist[i] = r3[0, 0, 0]
    grad[i, 0] = r3[1, 0, 0]
    grad[i, 1] = r3[0, 1, 0]
    if k == 3:
        hess[i, 0, 0] = r3[2, 0, 0]
        hess[i, 1, 1] = r3[0, 2, 0]
        hess[i, 0, 1] = hess[i, 1, 0] = r3[1, 1, 0]
    if dims == 3:
        grad[i, 2] = r3[0, 0, 1]
        if k == 3:
            hess[i, 2, 2] = r3[0, 0, 2]
            hess[i, 0, 2] = hess[i, 2, 0] = r3[1, 0, 1]
            hess[i, 1, 2] = hess[i, 2, 1] = r3[0, 1, 1]


@jit
def query_points(field, k, points, out, scratch):
    """:func:`query_point` at every row of ``points`` (N × 3), into the rows of ``out``."""
    for i in range(points.shape[0]):
        query_point(field, k, points[i], i, out, scratch)


def warm_up() -> None:
    """Compile :func:`query_points` (or load it from numba's on-disk cache) with the argument types
    of every :meth:`EsdfField.query`, so that no first query compiles in a service's loop."""
    EsdfField(np.ones((2, 2, 1), np.float32), (0.0, 0.0, 0.0), 1.0).query(np.zeros((1, 3)))


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


__all__ = ["FIELD_FLOATS", "FIELD_INTS", "KERNELS", "QUERY_SCRATCH", "QUERY_SCRATCH_SIZE", "EsdfField",
           "FieldSample", "Interpolation", "Kernel", "answer_query", "axis_weights", "kernel_view", "query_point",
           "query_points", "stencil_polynomials", "unknown_sample", "warm_up"]
