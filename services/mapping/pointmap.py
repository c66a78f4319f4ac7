"""Checks of an incoming pointmap frame before it touches the map.

A ``PerceptionFrame`` already has finite arrays of consistent shapes (the codec checks
that); what is left is what makes a frame absurd for mapping: a pose that is not a rigid
transform, a degenerate or gigantic image. ``FrameRejected`` names the problem.
"""

from __future__ import annotations

import numpy as np

ROTATION_TOL = 1e-3


class FrameRejected(ValueError):
    """A frame the mapper refuses; the message says why (for the rate-limited log)."""


def check_pose(T_WC: np.ndarray, tol: float = ROTATION_TOL) -> None:
    """``T_WC`` must be a finite 4x4 rigid transform: orthonormal rotation, det +1, last row 0 0 0 1."""
    T = np.asarray(T_WC, dtype=np.float64)
    if T.shape != (4, 4):
        raise FrameRejected(f"T_WC has shape {list(T.shape)}, expected [4, 4]")
    if not np.isfinite(T).all():
        raise FrameRejected("T_WC has NaN or Inf entries")
    if np.abs(T[3] - (0.0, 0.0, 0.0, 1.0)).max() > tol:
        raise FrameRejected(f"T_WC last row is {T[3].tolist()}, expected [0, 0, 0, 1]")
    R = T[:3, :3]
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > tol:
        raise FrameRejected(f"T_WC rotation is not orthonormal (max |RᵀR − I| = {err:.3g}; a Sim3 scale?)")
    det = float(np.linalg.det(R))
    if det < 0:
        raise FrameRejected(f"T_WC rotation is a reflection (det = {det:.3g})")
    if np.abs(T[:3, 3]).max() > 1e6:
        raise FrameRejected("T_WC translation is absurd (> 1000 km)")


def check_pointmap(points: np.ndarray, confidence: np.ndarray, labels: np.ndarray, max_pixels: int) -> None:
    """Shapes HxWx3 / HxW / HxW, at least one pixel, at most ``max_pixels``, finite points."""
    if points.ndim != 3 or points.shape[2] != 3:
        raise FrameRejected(f"points have shape {list(points.shape)}, expected HxWx3")
    hw = points.shape[:2]
    if confidence.shape != hw or labels.shape != hw:
        raise FrameRejected(
            f"shapes differ: points {list(hw)}, confidence {list(confidence.shape)}, labels {list(labels.shape)}"
        )
    n = hw[0] * hw[1]
    if n == 0:
        raise FrameRejected("the pointmap is empty")
    if n > max_pixels:
        raise FrameRejected(f"the pointmap has {n} pixels, over the limit of {max_pixels}")
    if not (np.isfinite(points).all() and np.isfinite(confidence).all()):
        raise FrameRejected("NaN or Inf in points or confidence")
