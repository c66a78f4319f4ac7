"""Compiled passes of the exact signed ESDF (``EsdfIntegrator``'s 3-D field).

The EDTs are ``distance_transform``'s; these kernels do the work around them in place of array
operations (per-group masks over the whole grid, boolean fancy indexing, the shifted-array face
tests). Each is one pass over the grid or a box, in the same float32 arithmetic as the array path
(``EsdfIntegrator._field``, which the 2-D slice runs), so both give the same field; the tests hold
the 3-D field equal to it (``tests/oracles/esdf.py``).

The passes loop over the first axis in parallel (``prange``, on ``EsdfParams.threads`` cores, as the
EDTs): each i-plane writes only its own voxels and its own row of the partial counts and boxes,
which are reduced serially afterwards; the bounding-box pass (``reach_box``) keeps its running
bounds in registers, not arrays.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ..runtime.jit import jit


@jit(parallel=True, error_model="numpy")
def scan(groups: np.ndarray, n_groups: int, voxel: np.float32) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                        np.ndarray]:
    """One pass over the group map: voxels per group, per-group bounding boxes, and the inside depth
    where it is one voxel (an occupied voxel with a free face neighbour inside the grid).

    Returns (counts (n+1,), lo (n+2, 3), hi (n+2, 3), depth f4); row n+1 of lo/hi is the bounding
    box of the *deep* occupied voxels (no free face neighbour), marked −1 in ``depth``. Free voxels
    have depth 0. Empty boxes have lo > hi.
    """
    nx, ny, nz = groups.shape
    depth = np.zeros(groups.shape, dtype=np.float32)
    cnt = np.zeros((nx, n_groups + 1), dtype=np.int64)
    lo = np.empty((nx, n_groups + 2, 3), dtype=np.int64)
    hi = np.empty((nx, n_groups + 2, 3), dtype=np.int64)
    for i in prange(nx):
        for g in range(n_groups + 2):
            for a in range(3):
                lo[i, g, a] = 1 << 40
                hi[i, g, a] = -1
        for j in range(ny):
            for k in range(nz):
                g = groups[i, j, k]
                if g == 0:  # most voxels: counted as the rest below
                    continue
                cnt[i, g] += 1
                exposed = ((i > 0 and groups[i - 1, j, k] == 0) or (i < nx - 1 and groups[i + 1, j, k] == 0)
                           or (j > 0 and groups[i, j - 1, k] == 0) or (j < ny - 1 and groups[i, j + 1, k] == 0)
                           or (k > 0 and groups[i, j, k - 1] == 0) or (k < nz - 1 and groups[i, j, k + 1] == 0))
                r = g
                if exposed:
                    depth[i, j, k] = voxel
                else:
                    depth[i, j, k] = -1.0
                for rr in range(2):
                    if rr == 1:
                        if exposed:
                            break
                        r = n_groups + 1
                    if i < lo[i, r, 0]:
                        lo[i, r, 0] = i
                    if i > hi[i, r, 0]:
                        hi[i, r, 0] = i
                    if j < lo[i, r, 1]:
                        lo[i, r, 1] = j
                    if j > hi[i, r, 1]:
                        hi[i, r, 1] = j
                    if k < lo[i, r, 2]:
                        lo[i, r, 2] = k
                    if k > hi[i, r, 2]:
                        hi[i, r, 2] = k
    counts = np.zeros(n_groups + 1, dtype=np.int64)
    glo = np.empty((n_groups + 2, 3), dtype=np.int64)
    ghi = np.empty((n_groups + 2, 3), dtype=np.int64)
    for g in range(n_groups + 2):
        for a in range(3):
            glo[g, a] = 1 << 40
            ghi[g, a] = -1
    for i in range(nx):
        for g in range(1, n_groups + 1):
            counts[g] += cnt[i, g]
        for g in range(n_groups + 2):
            for a in range(3):
                glo[g, a] = min(glo[g, a], lo[i, g, a])
                ghi[g, a] = max(ghi[g, a], hi[i, g, a])
    counts[0] = nx * ny * nz - counts[1:].sum()
    return counts, glo, ghi, depth


@jit(parallel=True, error_model="numpy")
def base_term(groups: np.ndarray, depth: np.ndarray, e: np.ndarray, base: int, half: np.float32,
              m_min: np.float32) -> np.ndarray:
    """The union term, in place of ``e``: on entry ``e`` is the distance to the nearest voxel of the
    other side (free ↔ occupied: the multi-label EDT, or the binary one with 0 inside); deep voxels
    (depth −1) take their depth from it. On return ``e`` holds e_U (0 inside) and the result is
    e_U − v/2 − m_min outside, −(depth − v/2) − m_min inside the base group, +inf inside the others."""
    nx, ny, nz = groups.shape
    dist = np.empty(groups.shape, dtype=np.float32)
    off = half + m_min
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                g = groups[i, j, k]
                if g == 0:
                    dist[i, j, k] = e[i, j, k] - off
                    continue
                if depth[i, j, k] < 0:
                    depth[i, j, k] = e[i, j, k]
                e[i, j, k] = 0.0
                if g == base:
                    dist[i, j, k] = -(depth[i, j, k] - half) - m_min
                else:
                    dist[i, j, k] = np.inf
    return dist


@jit
def _merge_boxes(plo: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box [lo, hi) holding the per-plane inclusive boxes (plo[n], phi[n]) of a parallel pass."""
    lo = np.array([1 << 40, 1 << 40, 1 << 40], dtype=np.int64)
    hi = np.array([-1, -1, -1], dtype=np.int64)
    for n in range(plo.shape[0]):
        for a in range(3):
            lo[a] = min(lo[a], plo[n, a])
            hi[a] = max(hi[a], phi[n, a])
    return lo, hi + 1


@jit(parallel=True, error_model="numpy")
def reach_box(e_union: np.ndarray, tlo: np.ndarray, thi: np.ndarray, llo: np.ndarray, lhi: np.ndarray,
              slack: np.float32, far: np.float32, voxel: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box [lo, hi) of the voxels of the loose box [llo, lhi) whose distance to the tight box
    [tlo, thi] (inclusive) is within ``slack`` of e_U and within ``far`` (``EsdfIntegrator._reach``)."""
    n = max(lhi[0] - llo[0], 0)
    plo = np.empty((n, 3), dtype=np.int64)
    phi = np.empty((n, 3), dtype=np.int64)
    for ii in prange(n):
        i = llo[0] + ii
        lo0, lo1, lo2 = 1 << 40, 1 << 40, 1 << 40
        hi0, hi1, hi2 = -1, -1, -1
        gi = np.float32(max(max(tlo[0] - i, i - thi[0]), 0)) * voxel
        for j in range(llo[1], lhi[1]):
            gj = np.float32(max(max(tlo[1] - j, j - thi[1]), 0)) * voxel
            bij = gi * gi + gj * gj
            for k in range(llo[2], lhi[2]):
                gk = np.float32(max(max(tlo[2] - k, k - thi[2]), 0)) * voxel
                b2 = bij + gk * gk
                limit = min(e_union[i, j, k] + slack, far)
                if b2 <= limit * limit:
                    lo0 = min(lo0, i)
                    hi0 = max(hi0, i)
                    lo1 = min(lo1, j)
                    hi1 = max(hi1, j)
                    lo2 = min(lo2, k)
                    hi2 = max(hi2, k)
        plo[ii, 0], plo[ii, 1], plo[ii, 2] = lo0, lo1, lo2
        phi[ii, 0], phi[ii, 1], phi[ii, 2] = hi0, hi1, hi2
    return _merge_boxes(plo, phi)


@jit(parallel=True, error_model="numpy")
def combine(box: tuple, g: int, base: int, numbers: tuple) -> None:
    """Fold group g's term into (dist, grp) on a box, ``box`` = (groups, depth, s, dist, grp): ``s``
    is e_g there (the EDT of the box); ``numbers`` = (half, m_g, off) float32, off = float32(v/2 +
    m_g). Ties go to the lower group id, but the base group yields every tie."""
    groups, depth, s, dist, grp = box
    half, m_g, off = numbers
    nx, ny, nz = groups.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                if groups[i, j, k] == g:
                    t = -(depth[i, j, k] - half) - m_g
                else:
                    t = s[i, j, k] - off
                cur = dist[i, j, k]
                cg = grp[i, j, k]
                if t < cur or (t == cur and (cg == base or g < cg)):
                    dist[i, j, k] = t
                    grp[i, j, k] = g


@jit(parallel=True, error_model="numpy")
def clip(dist: np.ndarray, grp: np.ndarray, dmax: np.float32) -> None:
    """d ≥ max_distance → max_distance with group 0 (nothing in range); d below −max_distance → −max_distance."""
    nx, ny, nz = dist.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                d = dist[i, j, k]
                if d >= dmax:
                    dist[i, j, k] = dmax
                    grp[i, j, k] = 0
                elif d < -dmax:
                    dist[i, j, k] = -dmax


@jit(parallel=True, error_model="numpy")
def diff_box(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box [lo, hi) of the voxels where two group maps differ (lo > hi − 1 when none), in
    one parallel pass instead of a difference mask and three reductions."""
    nx, ny, nz = a.shape
    plo = np.empty((nx, 3), dtype=np.int64)
    phi = np.empty((nx, 3), dtype=np.int64)
    for i in prange(nx):
        lo1, lo2, hi1, hi2 = 1 << 40, 1 << 40, -1, -1
        for j in range(ny):
            for k in range(nz):
                if a[i, j, k] != b[i, j, k]:
                    lo1 = min(lo1, j)
                    hi1 = max(hi1, j)
                    lo2 = min(lo2, k)
                    hi2 = max(hi2, k)
        plo[i, 0], plo[i, 1], plo[i, 2] = (i if hi1 >= 0 else 1 << 40), lo1, lo2
        phi[i, 0], phi[i, 1], phi[i, 2] = (i if hi1 >= 0 else -1), hi1, hi2
    return _merge_boxes(plo, phi)
