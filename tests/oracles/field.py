"""Oracle of the grid query: the field by array operations over all points at once, for the tests
to compare ``protocol.field.query_point`` (the one shipped query, compiled or interpreted) against.

The same definition (the module docstring of ``protocol.field``: stencil, central differences
through the interpolant or a cubic kernel's exact derivatives, linear extrapolation past the
border, nearest-voxel risk group, the in-map rule), written another way: each axis' weights as
matrices applied to the whole batch of stencils, where the shipped query evaluates the
polynomial weights of ``stencil_polynomials`` point by point.
"""

from __future__ import annotations

import numpy as np

from riskfield.protocol.field import _MATRIX, EsdfField, FieldSample, Kernel, axis_weights

_OFFS = np.arange(-1, 3)
_EPS = 1e-9

# Where the partial derivatives sit in the contracted tensor r[x-order, y-order(, z-order)].
_G2 = np.array([[1, 0], [0, 1]])
_H2 = np.array([[[2, 1], [1, 0]], [[0, 1], [1, 2]]])
_G3 = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]])
_H3 = np.array([
    [[2, 1, 1], [1, 0, 0], [1, 0, 0]],
    [[0, 1, 0], [1, 2, 1], [0, 1, 0]],
    [[0, 0, 1], [0, 0, 1], [1, 1, 2]],
])


def kernel_weights(t: np.ndarray, h: float, kernel: Kernel, orders: int) -> np.ndarray:
    """Per-axis stencil weights of the value and its first ``orders - 1`` derivatives of a cubic
    kernel: ``t`` (N, dims) fractions in the cell; (N, dims, orders, 4), row 0 the value, row 1 the
    first derivative (1/m), row 2 the second (1/m²)."""
    m = _MATRIX[kernel]
    t = np.asarray(t, np.float64)
    one, t2 = np.ones_like(t), t * t
    powers = [np.stack([one, t, t2, t2 * t], axis=-1)]
    if orders > 1:
        powers.append(np.stack([0 * t, one, 2 * t, 3 * t2], axis=-1) / h)
    if orders > 2:
        powers.append(np.stack([0 * t, 0 * t, 2 * one, 6 * t], axis=-1) / (h * h))
    return np.stack(powers, axis=-2) @ m.T


def _stencil(coeffs: np.ndarray, i0: np.ndarray, shape: np.ndarray, strides: np.ndarray) -> np.ndarray:
    """The 4^dims coefficients around each query's cell, linearly extrapolated past the border."""
    dims = len(shape)
    idx = [np.clip(i0[:, a, None] + _OFFS, 0, shape[a] - 1) * strides[a] for a in range(dims)]
    if dims == 2:
        flat = idx[0][:, :, None] + idx[1][:, None, :]
    else:
        flat = idx[0][:, :, None, None] + idx[1][:, None, :, None] + idx[2][:, None, None, :]
    block = coeffs[flat].astype(np.float64)
    for a in range(dims):
        lo = i0[:, a] == 0
        hi = i0[:, a] + 2 > shape[a] - 1
        b = np.moveaxis(block, a + 1, 1)  # a view: writes go to block
        b[lo, 0] = 2 * b[lo, 1] - b[lo, 2]
        b[hi, 3] = 2 * b[hi, 2] - b[hi, 1]
    return block


def array_query(field: EsdfField, points: np.ndarray, hessian: bool = False) -> FieldSample:
    """``field.query(points, hessian)`` by array operations."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n, dims = p.shape[0], 2 if field.planar else 3
    _, ny, nz = field.distance.shape
    shape, strides = np.array(field.distance.shape[:dims]), np.array([ny * nz, nz, 1])[:dims]
    upper = shape - 1.0
    u = (p[:, :dims] - field.origin[:dims]) / field.voxel_size
    inside = ((u >= -_EPS) & (u <= upper + _EPS)).all(axis=1)
    u = np.minimum(np.maximum(u, 0.0), upper)
    i0 = np.minimum(u.astype(np.int64), shape - 2)
    t = u - i0
    block = _stencil(field._flat, i0, shape, strides)
    k = 3 if hessian else 2
    if field.interpolation == "trilinear":
        w0, w1 = axis_weights(field.voxel_size)
        w = w0[:k] + t[:, :, None, None] * w1[:k]  # (N, dims, k, 4)
    else:
        w = kernel_weights(t, field.voxel_size, field.interpolation, k)
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
    nearest = np.minimum((u + 0.5).astype(np.int64), shape - 1)
    rg = field.risk_groups.reshape(-1)[nearest @ strides].astype(np.int64)
    return FieldSample(dist, grad, hess, rg, inside)
