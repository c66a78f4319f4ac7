"""Projective TSDF + semantic integration: voxels of the view frustum projected into the pointmap.

When a frame carries its pinhole intrinsics (``PerceptionFrame.intrinsics``: fx, fy, cx, cy of
the pointmap's own pixel grid), the update is *voxel-centric*, as nvblox's
``ProjectiveTsdfIntegrator`` does it (``nvblox/src/integrators/cuda/projective_tsdf_integrator.cu``:
the blocks in view come from ``ViewCalculator``, then every voxel of those blocks is projected into
the depth image and ``updateVoxel`` fuses ``surface_depth_measured − voxel_depth_m``, skipping
voxels more than the truncation behind the surface). Here, for each voxel centre ``x`` (world)
with camera-frame position ``c = R_WCᵀ (x − o)``, pixel ``(u, v) = round(fx·c_x/c_z + cx,
fy·c_y/c_z + cy)`` holds the point ``p`` and confidence ``q``; with ``r = |p|`` and ``t = |c|``
(ranges, not depths: the pointmap gives a metric point, and a range difference matches the
ray integrators' ``r − t_c`` on the pixel's ray),

    sdf = r − t,                     skipped if sdf < −τ,
    D ← (W·D + q'·min(sdf, τ)) / (W + q'),   W ← min(W + q', W_max),

where, in the band (|r − t| ≤ τ), the range difference is replaced by the point-to-plane distance
``(c − p)·n`` to the plane of the pixel's neighbours (n its normal, turned to the camera; kept
as is across depth jumps, at the image edge and where p is over 1.5 voxels from c, lest the
plane reach past a convex edge): the range difference overestimates the distance
by 1/cos θ at incidence θ, which leaves holes in the surface band of obliquely seen faces (the
floor, the top of a box), where the ray integrators are saved by evaluating every voxel on the ray
through its own hit point. q' = q·max(1, fx·fy·v²/c_z²) in the surface band (sdf ≤ τ; v the voxel
size: q times the pixels the voxel covers, as many as the ray integrators' rays that meet it)
where the plane is found, q where not (an isolated or edge pixel weighs one pixel), and
q' = ``carve_weight``·q in front of it (free
space: every voxel between the camera and the band is carved in the same pass, at no extra
cost, where the ray integrators walk a second, long ray). A free-space observation raises W only
up to ``max_free_weight`` (``TsdfParams``), so that a surface appearing in long-seen free space
shows within a few frames. Voxels in the band or behind it get ``hit = now``. Points beyond ``max_depth`` carve up
to ``max_depth − τ`` only; pixels below ``min_confidence`` or ``min_depth`` are skipped.
Voxels seen behind the surface (sdf < 0) store the viewing direction in ``view`` (×127, int8),
which the occupancy's solid fill marches along. Semantic votes take the same pass: a voxel with
|sdf| ≤ ``surface_band`` gets one vote (the paper's rule, ``semantic_integrator.vote``) for its
pixel's label with weight q.

Each voxel gets one observation per frame (the ray integrators give one per pixel or merged ray
that crosses it). Its surface weight counts the pixels it covers, so that a surface has the ray
integrators' weight per frame whatever the confidence's scale: with q = 1 (depth cameras, the
simulator's truth) and q per voxel, a person appearing in free space long seen (weight
``max_free_weight``) would need ~9 frames to reach the surface band, and one walking by never
would. Free space keeps q per voxel (the ray integrators carve with fewer rays than they fuse).

The grid is cut into cubic blocks of ``block_size`` voxels; a block is visited only if its
bounding sphere meets the view frustum (the four side planes, in front of the camera, nearer
than the farthest surface + τ), and the blocks run in parallel (numba ``prange``): each block
writes only its own voxels, so the threads never share a voxel (``integration_threads``, 1 by
default: see its note in ``config.py``).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from riskfield.protocol.kernels import Layout, view1, view2

from ..runtime.jit import jit, threads
from .config import TsdfParams
from .layers import SemanticLayer, TsdfLayer
from .pointmap import FrameRejected
from .semantic_integrator import vote
from .volume import Volume

#: One frame's numbers as ``_integrate_projective`` reads them: the camera (rotation, centre,
#: intrinsics fx, fy, cx, cy), the volume (origin, voxel size), ``TsdfParams``' thresholds and the
#: farthest usable range, in a float64 buffer ...
FLOATS = Layout("ProjectiveFloats", [("R", (3, 3)), ("camera", (3,)), ("origin", (3,)), ("K", (4,)),
                                     ("voxel", (1,)), ("free_max", (1,)), ("trunc", (1,)), ("w_max", (1,)),
                                     ("q_min", (1,)), ("r_min", (1,)), ("r_max", (1,)), ("band", (1,)),
                                     ("carve_scale", (1,)), ("far", (1,))])
#: ... and an int64 one: the clock (``TsdfLayer.hit``), the carving and voting switches, the block edge.
INTS = Layout("ProjectiveInts", [("now", (1,)), ("carve", (1,)), ("vote", (1,)), ("block", (1,))])
_PF, _PI = FLOATS.table(), INTS.table()
_F, _I = FLOATS.slot, INTS.slot


@jit(parallel=True, error_model="numpy")
def _far_range(points: np.ndarray, conf: np.ndarray, q_min: float, r_min: float, r_max: float) -> float:
    """Largest range (capped at ``r_max``) of the usable pixels; −1 when none is."""
    h = conf.shape[0]
    rows = np.full(h, -1.0)
    for v in prange(h):
        best = -1.0
        for u in range(conf.shape[1]):
            q = conf[v, u]
            if not q >= q_min or q <= 0.0:
                continue
            r = np.sqrt(points[v, u, 0] ** 2 + points[v, u, 1] ** 2 + points[v, u, 2] ** 2)
            if r >= r_min:
                best = max(best, min(r, r_max))
        rows[v] = best
    return rows.max()


@jit(error_model="numpy")
def _point_to_plane(points: np.ndarray, conf: np.ndarray, iv: int, iu: int, p: tuple, r: float, centre: tuple,
                    limits: tuple, sdf: float) -> tuple[float, bool]:
    """The band's signed distance from the voxel centre (x, y, z) to the plane of pixel (iv, iu)
    whose point p = (px, py, pz) is at range r, ``(c − p)·n`` with the pointmap's normal n turned to
    the camera, and True; ``sdf`` (the range difference) and False where the neighbours do not give
    a normal (image edge, invalid or across a depth jump) or the point is farther than ``reach``
    from the centre (the plane would reach past a convex edge). ``limits`` = (q_min, trunc, reach)."""
    px, py, pz = p
    x, y, z = centre
    q_min, trunc, reach = limits
    if (x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2 > reach * reach:
        return sdf, False
    h, w = conf.shape
    ul, ur, vu, vd = max(iu - 1, 0), min(iu + 1, w - 1), max(iv - 1, 0), min(iv + 1, h - 1)
    if ul == ur or vu == vd:
        return sdf, False
    for vv, uu in ((iv, ul), (iv, ur), (vu, iu), (vd, iu)):
        if not conf[vv, uu] >= q_min or conf[vv, uu] <= 0.0:
            return sdf, False
        rn = np.sqrt(points[vv, uu, 0] ** 2 + points[vv, uu, 1] ** 2 + points[vv, uu, 2] ** 2)
        if abs(rn - r) > trunc:
            return sdf, False  # a depth jump: no plane here
    ax = points[iv, ur, 0] - points[iv, ul, 0]
    ay = points[iv, ur, 1] - points[iv, ul, 1]
    az = points[iv, ur, 2] - points[iv, ul, 2]
    bx = points[vd, iu, 0] - points[vu, iu, 0]
    by = points[vd, iu, 1] - points[vu, iu, 1]
    bz = points[vd, iu, 2] - points[vu, iu, 2]
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    nn = np.sqrt(nx * nx + ny * ny + nz * nz)
    if not nn > 0.0:
        return sdf, False
    if nx * px + ny * py + nz * pz > 0.0:
        nn = -nn  # face the camera
    d = ((x - px) * nx + (y - py) * ny + (z - pz) * nz) / nn
    return min(max(d, -trunc), trunc), True


@jit(parallel=True, error_model="numpy")
def _integrate_projective(frame: tuple, layer: tuple, semantic: tuple, fl: np.ndarray, it: np.ndarray,
                          counts: np.ndarray) -> None:
    """Integrate ``frame`` = (points, confidence, labels) into ``layer`` = the ``TsdfLayer``'s (tsdf,
    weight, view, hit) and ``semantic`` = the ``SemanticLayer``'s (label, vote), with the frame's
    numbers ``fl``, ``it`` (``FLOATS``, ``INTS``); ``counts[b] = (voxels updated, votes)`` of block b
    (see the module doc)."""
    points, conf, labels = frame
    tsdf, weight, view, hit = layer
    lab, votes = semantic
    # Copies of the small arrays the parallel loop reads; scalars read once.
    R, o, origin = view2(fl, _PF, _F.R).copy(), view1(fl, _PF, _F.camera).copy(), view1(fl, _PF, _F.origin).copy()
    K = view1(fl, _PF, _F.K).copy()
    vs, free_max, trunc = view1(fl, _PF, _F.voxel)[0], view1(fl, _PF, _F.free_max)[0], view1(fl, _PF, _F.trunc)[0]
    w_max, q_min = view1(fl, _PF, _F.w_max)[0], view1(fl, _PF, _F.q_min)[0]
    r_min, r_max, band = view1(fl, _PF, _F.r_min)[0], view1(fl, _PF, _F.r_max)[0], view1(fl, _PF, _F.band)[0]
    carve_scale, far = view1(fl, _PF, _F.carve_scale)[0], view1(fl, _PF, _F.far)[0]
    now, carve = view1(it, _PI, _I.now)[0], view1(it, _PI, _I.carve)[0] != 0
    vote_labels, block = view1(it, _PI, _I.vote)[0] != 0, view1(it, _PI, _I.block)[0]
    h, w = conf.shape
    nx, ny, nz = tsdf.shape
    fx, fy, cx, cy = K[0], K[1], K[2], K[3]
    bx, by, bz = (nx + block - 1) // block, (ny + block - 1) // block, (nz + block - 1) // block
    # Inward unit normals of the frustum's side planes (camera frame, through the centre):
    # u ≥ −½, u ≤ w − ½, v ≥ −½, v ≤ h − ½.
    planes = np.array([[fx, 0.0, cx + 0.5], [-fx, 0.0, w - 0.5 - cx], [0.0, fy, cy + 0.5], [0.0, -fy, h - 0.5 - cy]])
    for m in range(4):
        planes[m] /= np.sqrt(planes[m, 0] ** 2 + planes[m, 1] ** 2 + planes[m, 2] ** 2)
    carve_to = min(far, r_max) - trunc  # where the band of the farthest usable surface begins
    foot = fx * fy * vs * vs  # pixels a voxel covers at camera depth 1 m
    for b in prange(bx * by * bz):
        ib, jb, kb = b // (by * bz), (b // bz) % by, b % bz
        i0, j0, k0 = ib * block, jb * block, kb * block
        i1, j1, k1 = min(i0 + block, nx), min(j0 + block, ny), min(k0 + block, nz)
        # Bounding sphere of the block's voxel centres, in the camera frame.
        rad = 0.5 * vs * np.sqrt((i1 - i0 - 1) ** 2 + (j1 - j0 - 1) ** 2 + (k1 - k0 - 1) ** 2)
        dx = origin[0] + vs * 0.5 * (i0 + i1 - 1) - o[0]
        dy = origin[1] + vs * 0.5 * (j0 + j1 - 1) - o[1]
        dz = origin[2] + vs * 0.5 * (k0 + k1 - 1) - o[2]
        pcx = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz
        pcy = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
        pcz = R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz
        if pcz + rad <= 0.0 or np.sqrt(dx * dx + dy * dy + dz * dz) - rad > far + trunc:
            continue
        outside = False
        for m in range(4):
            if planes[m, 0] * pcx + planes[m, 1] * pcy + planes[m, 2] * pcz < -rad:
                outside = True
        if outside:
            continue
        n_upd = 0
        n_votes = 0
        for i in range(i0, i1):
            for j in range(j0, j1):
                for k in range(k0, k1):
                    ex = origin[0] + vs * i - o[0]
                    ey = origin[1] + vs * j - o[1]
                    ez = origin[2] + vs * k - o[2]
                    z = R[0, 2] * ex + R[1, 2] * ey + R[2, 2] * ez
                    if z <= 1e-6:
                        continue
                    x = R[0, 0] * ex + R[1, 0] * ey + R[2, 0] * ez
                    y = R[0, 1] * ex + R[1, 1] * ey + R[2, 1] * ez
                    iu = int(np.floor(fx * x / z + cx + 0.5))
                    iv = int(np.floor(fy * y / z + cy + 0.5))
                    if iu < 0 or iv < 0 or iu >= w or iv >= h:
                        continue
                    q = conf[iv, iu]
                    if not q >= q_min or q <= 0.0:
                        continue
                    px, py, pz = points[iv, iu, 0], points[iv, iu, 1], points[iv, iu, 2]
                    r = np.sqrt(px * px + py * py + pz * pz)
                    if not r >= r_min:
                        continue
                    t = np.sqrt(ex * ex + ey * ey + ez * ez)
                    if r > r_max:
                        sdf = trunc + 1.0  # beyond range: only free space up to max_depth − τ
                        if t > r_max - trunc:
                            continue
                    else:
                        sdf = r - t
                    if sdf < -trunc:
                        continue
                    free = sdf > trunc
                    if free:
                        if not carve or t < r_min or t > carve_to:
                            continue
                        d, qq = trunc, q * carve_scale
                    else:
                        hit[i, j, k] = now
                        sdf, planar = _point_to_plane(points, conf, iv, iu, (px, py, pz), r, (x, y, z),
                                                      (q_min, trunc, 1.5 * vs), sdf)
                        # The ray integrators give a surface voxel one observation per pixel whose
                        # ray meets it; this pass gives one per voxel, so it weighs it by the pixels
                        # the voxel covers — where its pixel's neighbours agree on a plane, not for
                        # an isolated (flying) pixel, which the ray integrators weigh as one.
                        d, qq = sdf, q * max(1.0, foot / (z * z)) if planar else q
                        if sdf < 0.0:
                            view[i, j, k, 0] = np.int8(np.rint(127.0 * ex / t))
                            view[i, j, k, 1] = np.int8(np.rint(127.0 * ey / t))
                            view[i, j, k, 2] = np.int8(np.rint(127.0 * ez / t))
                        if vote_labels and abs(sdf) <= band:
                            nl, nw = vote(lab[i, j, k], votes[i, j, k], labels[iv, iu], q)
                            lab[i, j, k] = nl
                            votes[i, j, k] = nw
                            n_votes += 1
                    wv = weight[i, j, k]
                    tsdf[i, j, k] = (wv * tsdf[i, j, k] + qq * d) / (wv + qq)
                    cap = min(w_max, max(wv, free_max)) if free else w_max  # tsdf_integrator._update
                    wv += qq
                    weight[i, j, k] = cap if wv > cap else wv
                    n_upd += 1
        counts[b, 0] = n_upd
        counts[b, 1] = n_votes


class ProjectiveIntegrator:
    """TSDF and semantic votes of a frame with intrinsics, in one voxel-centric pass (module doc)."""

    def __init__(self, params: TsdfParams, surface_band: float):
        self.config, self.surface_band = params, surface_band  # as SemanticIntegrator's
        self._floats = np.zeros(Layout.size(_PF))
        self._ints = np.zeros(Layout.size(_PI), np.int64)

    def integrate(self, volume: Volume, tsdf: TsdfLayer, semantic: SemanticLayer | None, points: np.ndarray,
                  confidence: np.ndarray, labels: np.ndarray | None, T_WC: np.ndarray,
                  intrinsics: tuple[float, float, float, float] | np.ndarray, now_ms: int = 0) -> tuple[int, int]:
        """Fuse one frame seen at ``now_ms`` (the mapper's clock, for ``tsdf.hit``); returns (voxels
        updated, label votes). ``semantic=None``: TSDF only."""
        c = self.config
        K = np.asarray(intrinsics, dtype=np.float64).reshape(4)
        if not (np.isfinite(K).all() and K[0] > 0 and K[1] > 0):
            raise FrameRejected(f"intrinsics {K.tolist()}: fx, fy must be positive and all finite")
        T = np.asarray(T_WC, dtype=np.float64)
        pts = np.asarray(points, dtype=np.float32)
        conf = np.asarray(confidence, dtype=np.float32)
        with threads(c.integration_threads):
            return self._integrate(volume, tsdf, semantic, pts, conf, labels, T, K, int(now_ms))

    def _integrate(self, volume: Volume, tsdf: TsdfLayer, semantic: SemanticLayer | None, pts: np.ndarray,
                   conf: np.ndarray, labels: np.ndarray | None, T: np.ndarray, K: np.ndarray,
                   now_ms: int) -> tuple[int, int]:
        c = self.config
        far = float(_far_range(pts, conf, c.min_confidence, c.min_depth, c.max_depth))
        if far < 0.0:
            return 0, 0
        vote_labels = semantic is not None and labels is not None
        lab = np.asarray(labels, dtype=np.uint16) if vote_labels else np.zeros((1, 1), np.uint16)
        sem_lab = semantic.label if semantic is not None else np.zeros((1, 1, 1), np.uint16)
        sem_w = semantic.vote if semantic is not None else np.zeros((1, 1, 1), np.float32)
        nb = 1
        for n in tsdf.tsdf.shape:
            nb *= (n + c.block_size - 1) // c.block_size
        counts = np.zeros((nb, 2), np.int64)
        fl, it = self._floats, self._ints
        FLOATS.view(fl, _PF, "R")[:] = T[:3, :3]
        FLOATS.view(fl, _PF, "camera")[:] = T[:3, 3]
        FLOATS.view(fl, _PF, "origin")[:] = volume.origin
        FLOATS.view(fl, _PF, "K")[:] = K
        for name, value in (("voxel", volume.voxel_size), ("free_max", c.max_free_weight), ("trunc", tsdf.truncation),
                            ("w_max", c.max_weight), ("q_min", c.min_confidence), ("r_min", c.min_depth),
                            ("r_max", c.max_depth), ("band", self.surface_band), ("carve_scale", c.carve_weight),
                            ("far", far)):
            FLOATS.view(fl, _PF, name)[0] = value
        for name, value in (("now", now_ms), ("carve", int(c.carve)), ("vote", int(vote_labels)),
                            ("block", c.block_size)):
            INTS.view(it, _PI, name)[0] = value
        _integrate_projective((pts, conf, lab), (tsdf.tsdf, tsdf.weight, tsdf.view, tsdf.hit), (sem_lab, sem_w),
                              fl, it, counts)
        total = counts.sum(axis=0)
        return int(total[0]), int(total[1])
