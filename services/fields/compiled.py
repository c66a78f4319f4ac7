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

from ..runtime.jit import HAVE_NUMBA, numba
from . import spline as field_spline
from .grid import EsdfField
from .grid import axis_weights as trilinear_weights

_EPS = 1e-9  # the in-map tolerance of grid


def jit(fn):
    """``numba.njit`` with the on-disk cache (compiled once per install), or ``fn`` itself without numba."""
    return numba.njit(cache=True, nogil=True)(fn) if HAVE_NUMBA else fn


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


def kernel_view(field: EsdfField) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(coefficients float64, risk groups uint8, [dims, shape (3), strides (3)] int64,
    [origin (3), 1/h, stencil polynomials (48)] float64): ``field`` as :func:`query_point` reads it
    (few arrays: a call into numba costs per argument)."""
    flat = field._flat
    if flat.dtype != np.float64 or not flat.flags.writeable or not flat.flags.c_contiguous:
        flat = np.array(flat, np.float64)
    rgs = field._flat_rg
    if rgs.dtype != np.uint8 or not rgs.flags.writeable or not rgs.flags.c_contiguous:
        rgs = np.array(rgs, np.uint8)
    dims = 2 if field.planar else 3
    meta_i = np.zeros(7, np.int64)
    meta_i[0] = dims
    meta_i[1:4] = 1
    meta_i[1:1 + dims] = field._shape
    meta_i[4:4 + dims] = field._strides
    meta_f = np.zeros(52)
    meta_f[:dims] = field._origin_d
    meta_f[3] = field._inv_h
    meta_f[4:] = stencil_polynomials(field).ravel()
    return flat, rgs, meta_i, meta_f


@jit
def query_point(flat, rgs, dims, shape, strides, origin, inv_h, poly, k, p, i, dist, grad, hess, rg_out, inside,
           block, w, r1, r2, r3):
    """``EsdfField.query`` at one point p, into row i of the outputs (distance, gradient, Hessian when
    k = 3, risk group, inside); ``block``, ``w``, ``r1``-``r3`` are scratch ((4, 4, 4), (3, 3, 4),
    (4, 4, 3), (4, 3, 3), (3, 3, 3)). The field enters as :func:`kernel_view` gives it, its
    metadata unpacked: dims, shape and strides (3 each), origin (3), 1/h, polynomials (3, 4, 4)."""
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
