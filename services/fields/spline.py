"""Cubic interpolation kernels on the voxel grid of an ESDF, with exact derivatives.

The trilinear field of the paper has a piecewise-constant exact gradient; ``fields.grid`` works
around it with finite differences through the interpolant, which are continuous but are not
the derivatives of the distance they accompany (a CBF row then predicts a rate of h that h
does not have). Here the distance is a piecewise cubic whose gradient and Hessian are its own
exact derivatives. The kernels use the same 4-per-axis stencil (positions -1, 0, 1, 2 around
the query's cell, fraction t ∈ [0, 1) inside it) as ``fields.grid``, as a tensor product over
the 2 or 3 axes:

    d(x) = Σ_{i,j,k} c[i,j,k] w(tx)_i w(ty)_j w(tz)_k,
    ∂d/∂x = Σ c w'(tx)_i w(ty)_j w(tz)_k / h,     ∂²d/∂x∂y = Σ c w'(tx)_i w'(ty)_j w(tz)_k / h², …

* ``catmull_rom`` — Keys' cubic convolution with a = -½ (the Catmull-Rom spline), c = the
  grid values. Interpolating, C¹ (the gradient is continuous across cell faces; the Hessian is
  bounded but jumps there), reproduces polynomials up to degree 2 exactly.
* ``bspline`` — the uniform cubic B-spline on prefiltered coefficients: c solves the
  interpolation condition (a separable recursive filter, ``scipy.ndimage.spline_filter``), so
  the spline interpolates the grid and reproduces cubics exactly (away from the border, whose
  mirror condition fades as 0.27ⁿ over n voxels); it is C². The prefilter is global, though:
  a kink of the distance field (the ridge between two obstacles) rings into its neighbours
  with the same 0.27ⁿ decay (gradient errors of ~0.04 three voxels away from a ridge).
* ``bspline_smooth`` — the same B-spline on the samples themselves (no prefilter): a local,
  positive, C² smoother. It reproduces linear fields (walls) exactly and is off by
  h²/6 · ∂²d elsewhere (≈ 2 mm next to a 0.3 m sphere on 5 cm voxels; the filter's
  sampled-data margin δ of 2 cm covers it); at a ridge it averages towards the smaller
  distance (conservative). Its Hessian is continuous and, off the ridges, bounded like the
  true geometry's: the double integrator's default.

References: R. Keys, "Cubic convolution interpolation for digital image processing", IEEE
TASSP 29(6), 1981; M. Unser, "Splines: a perfect fit for signal and image processing", IEEE
SPM 16(6), 1999 (the B-spline prefilter; scipy implements it in ``ndimage/_interpolation.py``,
``spline_filter``).
"""

from __future__ import annotations

import numpy as np

# The kernels' weights are part of the grid query (riskfield.protocol.field, shared with external
# clients); only the prefilter, which needs scipy, lives here.
from riskfield.protocol.field import KERNELS, Kernel

__all__ = ["KERNELS", "Kernel", "prefilter"]


def prefilter(distance: np.ndarray, kernel: Kernel, planar: bool) -> np.ndarray:
    """The coefficients c the kernel is applied to (float64, same shape as ``distance``).

    Catmull-Rom and the smoothing B-spline use the samples themselves; the interpolating
    B-spline needs the prefilter along each grid axis (x, y and, unless ``planar``, z).
    """
    d = np.asarray(distance, np.float64)
    if kernel != "bspline":
        return d
    from scipy import ndimage  # imported here: only the B-spline needs it

    if planar:
        return ndimage.spline_filter(d[:, :, 0], order=3, mode="mirror")[:, :, None]
    return ndimage.spline_filter(d, order=3, mode="mirror")
