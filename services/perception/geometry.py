"""Rigid transforms of point arrays without BLAS.

``P @ R.T`` on an (N, 3) array calls a multi-threaded BLAS gemm whose threads spin-wait; on a
small machine shared with other processes that turned a 1 ms product into 50–100 ms. Three
fused multiply-adds per output column are as fast unloaded and never stall.
"""

from __future__ import annotations

import numpy as np


def transform_points(T: np.ndarray, P: np.ndarray, dtype: type = np.float64) -> np.ndarray:
    """``R·p + t`` for every row p of ``P`` (..., 3), with ``T`` a 4x4 (or 3x4) transform."""
    P = np.asarray(P)
    R, t = np.asarray(T, np.float64)[:3, :3], np.asarray(T, np.float64)[:3, 3]
    x, y, z = P[..., 0].astype(dtype), P[..., 1].astype(dtype), P[..., 2].astype(dtype)
    out = np.empty((*P.shape[:-1], 3), dtype)
    for i in range(3):
        out[..., i] = R[i, 0] * x + R[i, 1] * y + R[i, 2] * z + t[i]
    return out


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out
