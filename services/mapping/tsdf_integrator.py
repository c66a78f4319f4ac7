"""Pointmap + pose + confidence → TSDF by rays (the first step of the paper's Algorithm 1), for
frames without intrinsics.

A ``PerceptionFrame`` from an uncalibrated source (MASt3R-SLAM) carries no intrinsics, so the
projective pass (``projective_integrator.py``) cannot map voxels to pixels; the update follows
rays instead, and is the mapper's path for every frame when ``integration = "merged"``. A pixel's
camera-frame point ``p`` defines the ray from the camera centre ``o`` through it, at range
``r = |p|``. For every voxel the ray crosses within the truncation band, with ``t_c`` the
projection of the voxel centre ``c`` on the ray,

    sdf = r − t_c,                   kept if sdf ≥ −τ, clipped to sdf ≤ τ,
    D  ← (W·D + q·sdf) / (W + q),    W ← min(W + q, W_max),

where ``q`` is the observation's confidence (the SLAM matching confidence is the observation
weight, as in the paper), ``τ`` the truncation and ``W_max`` a cap that keeps the map able
to follow moving people and pets. Pixels with ``q < q_min``, non-positive or tiny range are
skipped; every ``pixel_stride``-th pixel in each image direction is used.

Rays are *merged* (the idea of voxblox's merged integrator): the pixels whose points fall into
the same voxel become one ray towards their confidence-weighted mean point, carrying their summed
confidence to the band and their mean confidence (one free-space observation) to the carving.
At 5 cm a 512×384 frame has tens of thousands of pixels but only a few thousand surface voxels,
so one ray per voxel is several times cheaper than one per pixel, for (nearly) the same surface
(``tests/mapping/test_tsdf.py`` compares it with one ray per pixel, the test oracle
``tests/oracles/tsdf.py``). Each merged ray also carves free space from the camera to its band
(D → τ) with weight ``carve_weight`` × the mean confidence, raising a voxel's weight only up to
``max_free_weight``: free-space evidence clears a moved obstacle within a few frames. A point
beyond ``max_depth`` or outside the volume keeps its own ray (its band may still reach in); beyond
``max_depth`` it only carves, up to ``max_depth``.
"""

from __future__ import annotations

import numpy as np

from riskfield.protocol.kernels import Layout, view1, view2

from ..runtime.jit import jit
from .config import TsdfParams
from .layers import TsdfLayer
from .raycast import pixel_ray, ray_voxels
from .volume import Volume

#: One integration's numbers as the kernels read them: the camera (rotation, centre), the volume
#: (origin, voxel size) and ``TsdfParams``' thresholds, in a float64 buffer ...
FLOATS = Layout("TsdfFloats", [("R", (3, 3)), ("camera", (3,)), ("origin", (3,)), ("voxel", (1,)),
                               ("free_max", (1,)), ("trunc", (1,)), ("w_max", (1,)), ("q_min", (1,)),
                               ("r_min", (1,)), ("r_max", (1,)), ("carve_scale", (1,))])
#: ... and an int64 one: the grid's shape, the clock (``TsdfLayer.hit``), the pixel stride and whether to carve.
INTS = Layout("TsdfInts", [("shape", (3,)), ("now", (1,)), ("stride", (1,)), ("carve", (1,))])
_TF, _TI = FLOATS.table(), INTS.table()
_F, _I = FLOATS.slot, INTS.slot


@jit(error_model="numpy")
def _update(tsdf: np.ndarray, weight: np.ndarray, i: int, j: int, k: int, d: float, q: float, w_max: float,
            cap_free: float) -> None:
    """One observation. The weight is capped at ``w_max``; a free-space one raises it only up to
    ``cap_free`` (or keeps it, if already above): old free space must not drown a surface that
    appears in it. A surface observation passes ``cap_free = w_max``."""
    w = weight[i, j, k]
    tsdf[i, j, k] = (w * tsdf[i, j, k] + q * d) / (w + q)
    cap = min(w_max, max(w, cap_free))
    w += q
    weight[i, j, k] = cap if w > cap else w


@jit(error_model="numpy")
def _ray(layer: tuple, fl: np.ndarray, it: np.ndarray, geo: np.ndarray, r: float, t0: float, t1: float,
         q: float, buf: np.ndarray) -> int:
    """Update the voxels the ray ``o + t·dw`` crosses for t in [t0, t1], surface at range ``r``.

    ``layer`` is the ``TsdfLayer``'s (tsdf, weight, view, hit); ``fl``, ``it`` the integration's
    numbers (``FLOATS``, ``INTS``); ``geo`` the rows o (the camera centre in index units), dw (the
    unit direction, world) and di = dw / vs; t is in metres. Voxels behind the surface (sdf < 0)
    keep the ray's direction in ``view`` (×127, int8): the occupancy's fill of never-observed space
    behind surfaces marches along it. Voxels in the band or behind it get ``hit = now``.
    """
    tsdf, weight, view, hit = layer
    vs, trunc = view1(fl, _TF, _F.voxel)[0], view1(fl, _TF, _F.trunc)[0]
    w_max, free_max = view1(fl, _TF, _F.w_max)[0], view1(fl, _TF, _F.free_max)[0]
    now = view1(it, _TI, _I.now)[0]
    o, dw, di = geo[0], geo[1], geo[2]
    n = ray_voxels(o, di, t0, t1, view1(it, _TI, _I.shape), buf)
    for m in range(n):
        i, j, k = buf[m, 0], buf[m, 1], buf[m, 2]
        tc = ((i - o[0]) * dw[0] + (j - o[1]) * dw[1] + (k - o[2]) * dw[2]) * vs
        sdf = r - tc
        if sdf < -trunc:
            continue
        cap_free = w_max
        if sdf > trunc:
            sdf = trunc
            cap_free = free_max
        else:
            hit[i, j, k] = now
            if sdf < 0.0:
                for a in range(3):
                    view[i, j, k, a] = np.int8(np.rint(127.0 * dw[a]))
        _update(tsdf, weight, i, j, k, sdf, q, w_max, cap_free)
    return n


@jit(error_model="numpy")
def _integrate_merged(frame: tuple, layer: tuple, fl: np.ndarray, it: np.ndarray, scratch: tuple) -> int:
    """Merged rays of ``frame`` = (points, confidence): the pixels whose points fall in one voxel
    become one ray to their weighted mean.

    ``scratch`` = (acc_q, acc_n, acc_p, touched): all-zero arrays over the flattened grid (and one
    index per pixel); they are zero again on return.
    """
    points, conf = frame
    acc_q, acc_n, acc_p, touched = scratch
    R = view2(fl, _TF, _F.R)
    vs, trunc = view1(fl, _TF, _F.voxel)[0], view1(fl, _TF, _F.trunc)[0]
    q_min, r_min, r_max = view1(fl, _TF, _F.q_min)[0], view1(fl, _TF, _F.r_min)[0], view1(fl, _TF, _F.r_max)[0]
    carve_scale = view1(fl, _TF, _F.carve_scale)[0]
    stride, carve = view1(it, _TI, _I.stride)[0], view1(it, _TI, _I.carve)[0] != 0
    h, w = conf.shape
    shape = view1(it, _TI, _I.shape)
    nx, ny, nz = shape[0], shape[1], shape[2]
    buf = np.empty((shape.sum() + 4, 3), dtype=np.int64)
    geo = np.empty((3, 3))
    o, dw, di = geo[0], geo[1], geo[2]
    o[:] = (view1(fl, _TF, _F.camera) - view1(fl, _TF, _F.origin)) / vs
    pw = np.empty(3)
    n_touched = 0
    used = 0
    for v in range(0, h, stride):
        for u in range(0, w, stride):
            q, r = pixel_ray(points, conf, R, v, u, q_min, r_min, dw)
            if r < 0.0:
                continue
            for a in range(3):
                pw[a] = o[a] + dw[a] * r / vs  # the point in index units
            i = int(np.floor(pw[0] + 0.5))
            j = int(np.floor(pw[1] + 0.5))
            k = int(np.floor(pw[2] + 0.5))
            if r > r_max or i < 0 or j < 0 or k < 0 or i >= nx or j >= ny or k >= nz:
                # Beyond range or outside the volume: its own ray (the band may still reach in).
                for a in range(3):
                    di[a] = dw[a] / vs
                n = 0
                if r <= r_max:
                    n += _ray(layer, fl, it, geo, r, r - trunc, r + trunc, q, buf)
                t1 = min(r, r_max) - trunc
                if carve and t1 > r_min:
                    n += _ray(layer, fl, it, geo, r, r_min, t1, q * carve_scale, buf)
                if n > 0:
                    used += 1
                continue
            f = (i * ny + j) * nz + k
            if acc_n[f] == 0:
                touched[n_touched] = f
                n_touched += 1
            acc_n[f] += 1
            acc_q[f] += q
            acc_p[f, 0] += q * (pw[0] - i)
            acc_p[f, 1] += q * (pw[1] - j)
            acc_p[f, 2] += q * (pw[2] - k)
    for m in range(n_touched):
        f = touched[m]
        k = f % nz
        j = (f // nz) % ny
        i = f // (ny * nz)
        qs = acc_q[f]
        cnt = acc_n[f]
        r2 = 0.0
        for a in range(3):
            c = (i, j, k)[a] + acc_p[f, a] / qs
            dw[a] = (c - o[a]) * vs
            r2 += dw[a] * dw[a]
        r = np.sqrt(r2)
        acc_q[f] = 0.0
        acc_n[f] = 0
        acc_p[f, 0] = 0.0
        acc_p[f, 1] = 0.0
        acc_p[f, 2] = 0.0
        if not r >= r_min:
            continue
        for a in range(3):
            dw[a] /= r
            di[a] = dw[a] / vs
        n = _ray(layer, fl, it, geo, r, r - trunc, r + trunc, qs, buf)
        t1 = r - trunc
        if carve and t1 > r_min:
            # One free-space observation per merged ray, of the pixels' mean confidence.
            n += _ray(layer, fl, it, geo, r, r_min, t1, qs / cnt * carve_scale, buf)
        if n > 0:
            used += cnt
    return used


class TsdfIntegrator:
    """Integrates camera-frame pointmaps into a ``TsdfLayer`` (see the module docstring)."""

    def __init__(self, params: TsdfParams):
        self.config = params
        self._scratch: tuple[np.ndarray, ...] | None = None
        self._floats = np.zeros(Layout.size(_TF))
        self._ints = np.zeros(Layout.size(_TI), np.int64)

    def _buffers(self, n_voxels: int, n_pixels: int) -> tuple[np.ndarray, ...]:
        s = self._scratch
        if s is None or s[0].shape[0] != n_voxels or s[3].shape[0] < n_pixels:
            s = self._scratch = (np.zeros(n_voxels, np.float32), np.zeros(n_voxels, np.int32),
                                 np.zeros((n_voxels, 3), np.float32), np.empty(n_pixels, np.int64))
        return s

    def _numbers(self, volume: Volume, layer: TsdfLayer, T: np.ndarray, now_ms: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``FLOATS`` and ``INTS`` buffers of one frame."""
        c, fl, it = self.config, self._floats, self._ints
        FLOATS.view(fl, _TF, "R")[:] = T[:3, :3]
        FLOATS.view(fl, _TF, "camera")[:] = T[:3, 3]
        FLOATS.view(fl, _TF, "origin")[:] = volume.origin
        for name, value in (("voxel", volume.voxel_size), ("free_max", c.max_free_weight),
                            ("trunc", layer.truncation), ("w_max", c.max_weight), ("q_min", c.min_confidence),
                            ("r_min", c.min_depth), ("r_max", c.max_depth), ("carve_scale", c.carve_weight)):
            FLOATS.view(fl, _TF, name)[0] = value
        INTS.view(it, _TI, "shape")[:] = layer.tsdf.shape
        for name, value in (("now", int(now_ms)), ("stride", c.pixel_stride), ("carve", int(c.carve))):
            INTS.view(it, _TI, name)[0] = value
        return fl, it

    def integrate(self, volume: Volume, layer: TsdfLayer, points: np.ndarray, confidence: np.ndarray,
                  T_WC: np.ndarray, now_ms: int = 0) -> int:
        """Fuse one frame seen at ``now_ms`` (the mapper's clock, for ``layer.hit``); returns the
        number of pixels whose rays reached the volume."""
        fl, it = self._numbers(volume, layer, np.asarray(T_WC, dtype=np.float64), now_ms)
        frame = (np.asarray(points, dtype=np.float32), np.asarray(confidence, dtype=np.float32))
        arrays = (layer.tsdf, layer.weight, layer.view, layer.hit)
        return int(_integrate_merged(frame, arrays, fl, it, self._buffers(layer.tsdf.size, frame[1].size)))
