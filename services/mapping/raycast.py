"""Voxel traversal along a ray (Amanatides & Woo), the kernel both integrators share.

Works in *continuous index* space where voxel i covers [i − ½, i + ½) on each axis (voxel
centres at integers, the ``Volume`` convention). ``ray_voxels`` writes, in order along the
ray, every voxel whose cube the segment ``o + t·d, t ∈ [t0, t1]`` crosses and that lies in
the grid, and returns how many. Compiled with numba; plain numpy arrays in and out.
"""

from __future__ import annotations

import numpy as np

from ..runtime.jit import jit

_EPS = 1e-9


@jit(error_model="numpy")
def pixel_ray(points: np.ndarray, conf: np.ndarray, R: np.ndarray, v: int, u: int, q_min: float, r_min: float,
              dw: np.ndarray) -> tuple[float, float]:
    """Confidence ``q`` and range ``r`` of pixel (v, u), its world-frame unit ray direction
    written into ``dw``; ``r = -1`` marks a pixel every integrator skips (confidence below
    ``q_min`` or not positive, NaN, range below ``r_min``)."""
    q = conf[v, u]
    if not q >= q_min or q <= 0.0:
        return q, -1.0
    px = points[v, u, 0]
    py = points[v, u, 1]
    pz = points[v, u, 2]
    r = np.sqrt(px * px + py * py + pz * pz)
    if not r >= r_min:
        return q, -1.0
    # The rotation is written out rather than calling geometry.transforms: numba cannot call it,
    # and this runs once per pixel.
    for a in range(3):
        dw[a] = (R[a, 0] * px + R[a, 1] * py + R[a, 2] * pz) / r
    return q, r


@jit(error_model="numpy")
def clip_to_box(o: np.ndarray, d: np.ndarray, t0: float, t1: float, shape: np.ndarray) -> tuple[float, float]:
    """Slab test of the segment against the grid box [−½, n − ½)³ (index units); empty → t0 > t1."""
    for a in range(3):
        lo = -0.5
        hi = shape[a] - 0.5
        if abs(d[a]) < _EPS:
            if o[a] < lo or o[a] >= hi:
                return 1.0, 0.0
        else:
            ta = (lo - o[a]) / d[a]
            tb = (hi - o[a]) / d[a]
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
    return t0, t1


@jit(error_model="numpy")
def _axis_init(o: float, d: float, tm: float, n: int) -> tuple[int, int, float, float]:
    """Start voxel, step, t of the first boundary crossing and t between crossings on one axis."""
    i = int(np.floor(o + tm * d + 0.5))
    if i < 0:
        i = 0
    elif i >= n:
        i = n - 1
    if d > _EPS:
        return i, 1, (i + 0.5 - o) / d, 1.0 / d
    if d < -_EPS:
        return i, -1, (i - 0.5 - o) / d, -1.0 / d
    return i, 0, np.inf, np.inf


@jit(error_model="numpy")
def ray_voxels(o: np.ndarray, d: np.ndarray, t0: float, t1: float, shape: np.ndarray, out: np.ndarray) -> int:
    """Voxels crossed by ``o + t·d`` for t in [t0, t1] (``o``, ``d`` in index units), into ``out`` (M×3).

    ``d`` need not be normalised; t is in the units of ``d``. Returns the count written
    (at most ``out.shape[0]``). Allocation-free: it runs once per pixel.
    """
    t0, t1 = clip_to_box(o, d, t0, t1, shape)
    if t0 > t1:
        return 0
    tm = 0.5 * (t0 + t1) if t1 - t0 < 1e-6 else t0 + 1e-7 * (t1 - t0)
    nx, ny, nz = shape[0], shape[1], shape[2]
    ix, sx, mx, dx = _axis_init(o[0], d[0], tm, nx)
    iy, sy, my, dy = _axis_init(o[1], d[1], tm, ny)
    iz, sz, mz, dz = _axis_init(o[2], d[2], tm, nz)
    n = 0
    cap = out.shape[0]
    while n < cap:
        out[n, 0] = ix
        out[n, 1] = iy
        out[n, 2] = iz
        n += 1
        if mx <= my and mx <= mz:
            if mx > t1:
                break
            ix += sx
            if ix < 0 or ix >= nx:
                break
            mx += dx
        elif my <= mz:
            if my > t1:
                break
            iy += sy
            if iy < 0 or iy >= ny:
                break
            my += dy
        else:
            if mz > t1:
                break
            iz += sz
            if iz < 0 or iz >= nz:
                break
            mz += dz
    return n


def ray_voxels_py(origin: np.ndarray, direction: np.ndarray, t0: float, t1: float,
                  shape: tuple[int, int, int]) -> np.ndarray:
    """Convenience wrapper (tests, tools): the crossed voxel indices as an (M, 3) array."""
    out = np.empty((sum(shape) + 4, 3), dtype=np.int64)
    n = ray_voxels(np.asarray(origin, np.float64), np.asarray(direction, np.float64), float(t0), float(t1),
                   np.asarray(shape, np.int64), out)
    return out[:n].copy()
