"""A compiled (numba) query of an :class:`~.grid.EsdfField` at one point, for compiled callers.

:func:`query_point` is :meth:`EsdfField.query <.grid.EsdfField.query>` for a single point — the
same in-map rule, stencil, linear extrapolation past the border, nearest-voxel risk group — as
a ``numba.njit`` function that writes into caller-owned rows and scratch, so a compiled control
step (``safety_filter.compiled``) queries the field without leaving machine code or allocating.
``tests/fields/test_compiled_query.py`` checks it against ``EsdfField.query`` on random points.

Each axis' stencil weights are polynomials in the cell fraction t: w[o, p](t) = Σ_q P[o, p, q] tᵠ
for the value (o = 0), first (o = 1) and second (o = 2) derivative at stencil position p; the
trilinear finite-difference weights (``grid.axis_weights``) and the cubic kernels (``spline``)
both take this form (:func:`stencil_polynomials`), so one contraction serves all four
interpolations.

The field enters as one contiguous float64 array of coefficients and one uint8 array of risk
groups (:func:`kernel_view` converts once per map when a message's arrays are of another type or
read-only): numba compiles per argument type, and one specialisation should serve every map.
Not imported by ``fields/__init__``: numba is an extra (``robot``, ``mapping``), not a need of
the field API.
"""

from __future__ import annotations

import numpy as np

from ..runtime.jit import jit
from ..runtime.kernels import Layout, view1, view3
from . import spline as field_spline
from .grid import EsdfField
from .grid import axis_weights as trilinear_weights

_EPS = 1e-9  # the in-map tolerance of grid


def stencil_polynomials(field: EsdfField) -> np.ndarray:
    """P (3, 4, 4): per-axis weights w[o, p](t) = Σ_q P[o, p, q] t^q of the field's interpolation."""
    h = field.voxel_size
    poly = np.zeros((3, 4, 4))
    if field.interpolation == "trilinear":
        w0, w1 = trilinear_weights(h)
        poly[:, :, 0], poly[:, :, 1] = w0, w1
        return poly
    m = field_spline._MATRIX[field.interpolation]  # w_p(t) = Σ_k M[p, k] t^k
    for q in range(4):
        poly[0, :, q] = m[:, q]
        if q >= 1:
            poly[1, :, q - 1] = m[:, q] * q / h
        if q >= 2:
            poly[2, :, q - 2] = m[:, q] * q * (q - 1) / (h * h)
    return poly


# --------------------------------------------------------------------------- field query

#: The field's metadata as :func:`query_point` reads it (:func:`kernel_view`).
FIELD_INTS = Layout("FieldInts", [("dims", (1,)), ("shape", (3,)), ("strides", (3,))])
FIELD_FLOATS = Layout("FieldFloats", [("origin", (3,)), ("inv_h", (1,)), ("poly", (3, 4, 4))])
_FI, _FF = FIELD_INTS.table(), FIELD_FLOATS.table()
_FIS, _FFS = FIELD_INTS.slot, FIELD_FLOATS.slot


def kernel_view(field: EsdfField) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(coefficients float64, risk groups uint8, metadata int64 (:data:`FIELD_INTS`), metadata
    float64 (:data:`FIELD_FLOATS`)): ``field`` as :func:`query_point` reads it (few arrays: a call
    into numba costs per argument)."""
    flat = field._flat
    if flat.dtype != np.float64 or not flat.flags.writeable or not flat.flags.c_contiguous:
        flat = np.array(flat, np.float64)
    rgs = field._flat_rg
    if rgs.dtype != np.uint8 or not rgs.flags.writeable or not rgs.flags.c_contiguous:
        rgs = np.array(rgs, np.uint8)
    dims = 2 if field.planar else 3
    meta_i = np.zeros(Layout.size(_FI), np.int64)
    FIELD_INTS.view(meta_i, _FI, "dims")[0] = dims
    shape = FIELD_INTS.view(meta_i, _FI, "shape")
    shape[:] = 1
    shape[:dims] = field._shape
    FIELD_INTS.view(meta_i, _FI, "strides")[:dims] = field._strides
    meta_f = np.zeros(Layout.size(_FF))
    FIELD_FLOATS.view(meta_f, _FF, "origin")[:dims] = field._origin_d
    FIELD_FLOATS.view(meta_f, _FF, "inv_h")[0] = field._inv_h
    FIELD_FLOATS.view(meta_f, _FF, "poly")[:] = stencil_polynomials(field)
    return flat, rgs, meta_i, meta_f


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
    """``EsdfField.query`` at one point p, into row i of ``out`` = (distance, gradient, Hessian
    when k = 3, risk group, inside). ``field`` is the tuple :func:`kernel_view` gives;
    ``scratch`` holds :data:`QUERY_SCRATCH_SIZE` floats."""
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
    flat_near = nx * strides[0] + ny * strides[1]
    if dims == 3:
        flat_near += nz * strides[2]
    rg_out[i] = rgs[flat_near]
    # The 4^dims stencil, clamped to the grid, then clamped layers replaced by linear extrapolation.
    nzs = 4 if dims == 3 else 1
    for a in range(4):
        xa = min(max(ix0 - 1 + a, 0), shape[0] - 1) * strides[0]
        for b in range(4):
            yb = min(max(iy0 - 1 + b, 0), shape[1] - 1) * strides[1]
            if dims == 3:
                for c in range(4):
                    zc = min(max(iz0 - 1 + c, 0), shape[2] - 1) * strides[2]
                    block[a, b, c] = flat[xa + yb + zc]
            else:
                block[a, b, 0] = flat[xa + yb]
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
    for a in range(3):
        grad[i, a] = 0.0
        for b in range(3):
            hess[i, a, b] = 0.0
    if dims == 2:
        # r[ox, oy] = Σ_ab wx[ox, a] block[a, b] wy[oy, b]
        for a in range(4):
            for oy in range(k):
                s = 0.0
                for b in range(4):
                    s += block[a, b, 0] * w[1, oy, b]
                r1[a, oy, 0] = s
        for ox in range(k):
            for oy in range(k):
                s = 0.0
                for a in range(4):
                    s += w[0, ox, a] * r1[a, oy, 0]
                r3[ox, oy, 0] = s
        dist[i] = r3[0, 0, 0]
        grad[i, 0] = r3[1, 0, 0]
        grad[i, 1] = r3[0, 1, 0]
        if k == 3:
            hess[i, 0, 0] = r3[2, 0, 0]
            hess[i, 0, 1] = r3[1, 1, 0]
            hess[i, 1, 0] = r3[1, 1, 0]
            hess[i, 1, 1] = r3[0, 2, 0]
        return
    # Contract z, then y, then x (the order of fields.grid).
    for a in range(4):
        for b in range(4):
            for oz in range(k):
                s = 0.0
                for c in range(4):
                    s += block[a, b, c] * w[2, oz, c]
                r1[a, b, oz] = s
    for a in range(4):
        for oy in range(k):
            for oz in range(k):
                s = 0.0
                for b in range(4):
                    s += w[1, oy, b] * r1[a, b, oz]
                r2[a, oy, oz] = s
    for ox in range(k):
        for oy in range(k):
            for oz in range(k):
                s = 0.0
                for a in range(4):
                    s += w[0, ox, a] * r2[a, oy, oz]
                r3[ox, oy, oz] = s
    dist[i] = r3[0, 0, 0]
    grad[i, 0] = r3[1, 0, 0]
    grad[i, 1] = r3[0, 1, 0]
    grad[i, 2] = r3[0, 0, 1]
    if k == 3:
        hess[i, 0, 0] = r3[2, 0, 0]
        hess[i, 1, 1] = r3[0, 2, 0]
        hess[i, 2, 2] = r3[0, 0, 2]
        hess[i, 0, 1] = hess[i, 1, 0] = r3[1, 1, 0]
        hess[i, 0, 2] = hess[i, 2, 0] = r3[1, 0, 1]
        hess[i, 1, 2] = hess[i, 2, 1] = r3[0, 1, 1]
