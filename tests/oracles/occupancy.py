"""Semantic occupancy by whole-volume scans, as a test oracle of the mapper's sparse passes
(``services/mapping/occupancy.py``, ``_solid``): after the wavefront, the production kernel visits
only the columns with an observed obstacle voxel (the fill below obstacles), closes the pinholes on
bit planes, 64 voxels of a column to a word, the second pass only beside the voxels the first one
closed, and visits the voxels the wavefront reached (the free mark's clearing, without
``unknown_group``); this oracle runs the same passes over every column, voxel by voxel around every
filled voxel, and over every voxel, which must give the same groups
(tests/mapping/test_support_fill.py). Plain Python: the tests' grids are a few thousand voxels.
"""

from __future__ import annotations

import numpy as np

from riskfield.services.mapping.layers import NO_LABEL, SemanticLayer, TsdfLayer
from riskfield.services.mapping.occupancy import _FREE, OccupancyRule, _enqueue_by_priority
from riskfield.services.mapping.raycast import ray_voxels


def _solid_at(f: int, state: np.ndarray, filled: np.ndarray, g: np.ndarray) -> bool:
    """Voxel ``f`` is part of an obstacle: filled, or observed interior / surface of an obstacle group."""
    return bool(filled[f] or (state[f] == 3 and g[f] != _FREE and g[f] != 0))


def whole_volume_occupancy(tsdf: TsdfLayer, semantic: SemanticLayer, label_to_group: np.ndarray,
                           rule: OccupancyRule) -> np.ndarray:
    """``semantic_occupancy(tsdf, semantic, label_to_group, rule)`` of a ``"solid"`` interior by
    whole-volume scans: per-voxel obstacle group (uint8, 0 = not an obstacle)."""
    if rule.interior != "solid":
        raise ValueError("the oracle covers the solid interior (the shell is array operations already)")
    groups = np.zeros(tsdf.tsdf.shape, dtype=np.uint8)
    layers = (np.ascontiguousarray(tsdf.tsdf), np.ascontiguousarray(tsdf.weight), np.ascontiguousarray(tsdf.view),
              np.ascontiguousarray(semantic.label))
    numbers = (float(max(rule.min_weight, 1e-12)), float(rule.surface_band), int(rule.fill_steps),
               int(rule.unknown_group), int(rule.support_steps))
    _solid(layers, np.ascontiguousarray(label_to_group, dtype=np.uint8), numbers, groups)
    return groups


def _solid(layers: tuple, lut: np.ndarray, rule: tuple, groups: np.ndarray) -> None:
    """Fill ``groups`` (all zero on entry) with the solid semantic occupancy of ``layers`` = (tsdf,
    weight, view, label), scanning the whole volume in every pass after the wavefront. ``rule`` =
    (min_w, band, fill_steps, unknown_group, support_steps), as the production kernel's."""
    tsdf, weight, view, label = layers
    min_w, band, fill_steps, unknown_group, support_steps = rule
    nx, ny, nz = tsdf.shape
    n = nx * ny * nz
    t = tsdf.reshape(n)
    w = weight.reshape(n)
    lab = label.reshape(n)
    g = groups.reshape(n)
    # 0: free / outside, 1: observed interior not yet reached, 2: never observed, not yet reached,
    # 3: assigned a group (or the free mark).
    state = np.zeros(n, np.uint8)
    cand = np.empty(n, np.int64)
    queue = np.empty(n, np.int64)
    n_cand = 0
    for f in range(n):
        if w[f] < min_w:
            state[f] = 2
            continue
        d = t[f]
        if abs(d) <= band and lab[f] != NO_LABEL:
            gg = lut[lab[f]]
            g[f] = gg if gg > 0 else _FREE
            state[f] = 3
            cand[n_cand] = f
            n_cand += 1
        elif d < -band:
            state[f] = 1  # unlabelled band voxels stay out: the spurious crossings behind edges
    sy, sx = nz, ny * nz
    # The observed interior takes the group of its nearest labelled surface voxel (wavefront).
    tail = _enqueue_by_priority(cand, n_cand, g, queue)
    head = 0
    while head < tail:
        f = queue[head]
        head += 1
        k = f % nz
        j = (f // nz) % ny
        i = f // sx
        for a in range(6):
            if a == 0:
                if i == 0:
                    continue
                nb = f - sx
            elif a == 1:
                if i == nx - 1:
                    continue
                nb = f + sx
            elif a == 2:
                if j == 0:
                    continue
                nb = f - sy
            elif a == 3:
                if j == ny - 1:
                    continue
                nb = f + sy
            elif a == 4:
                if k == 0:
                    continue
                nb = f - 1
            else:
                if k == nz - 1:
                    continue
                nb = f + 1
            if state[nb] == 1:
                state[nb] = 3
                g[nb] = g[f]
                queue[tail] = nb
                tail += 1
    if fill_steps > 0:
        # Never-observed voxels behind the observed interior: from each interior voxel of an
        # obstacle that borders never-observed space, march on along the viewing direction of
        # the ray that saw it behind the surface, through never-observed or interior voxels.
        vw = view.reshape(n, 3)
        filled = np.zeros(n, np.bool_)
        shape = np.array(tsdf.shape, dtype=np.int64)
        buf = np.empty((shape.sum() + 4, 3), dtype=np.int64)
        o = np.empty(3)
        d = np.empty(3)
        n_marked = 0  # ``cand`` now lists the marked voxels
        for m in range(tail):  # the queue holds every voxel the wavefront assigned
            f = queue[m]
            if g[f] == _FREE or w[f] < min_w or not t[f] < 0.0:
                continue
            k = f % nz
            j = (f // nz) % ny
            i = f // sx
            border = ((i > 0 and state[f - sx] == 2) or (i < nx - 1 and state[f + sx] == 2)
                      or (j > 0 and state[f - sy] == 2) or (j < ny - 1 and state[f + sy] == 2)
                      or (k > 0 and state[f - 1] == 2) or (k < nz - 1 and state[f + 1] == 2))
            if not border:
                continue
            ux, uy, uz = float(vw[f, 0]), float(vw[f, 1]), float(vw[f, 2])
            norm = np.sqrt(ux * ux + uy * uy + uz * uz)
            if norm < 1.0:
                continue  # never seen behind a surface (a labelled voxel in front of it)
            o[0], o[1], o[2] = float(i), float(j), float(k)
            d[0], d[1], d[2] = ux / norm, uy / norm, uz / norm
            # every voxel the segment of length D crosses (Amanatides & Woo), the source first
            m_vox = ray_voxels(o, d, 0.0, float(fill_steps), shape, buf)
            for m in range(1, m_vox):
                nb = (buf[m, 0] * ny + buf[m, 1]) * nz + buf[m, 2]
                st = state[nb]
                if st == 2:
                    if not filled[nb]:
                        filled[nb] = True
                        g[nb] = g[f]
                        cand[n_marked] = nb
                        n_marked += 1
                elif st == 0 or g[nb] == _FREE:
                    break  # observed free space, or a free-labelled surface: the obstacle ends
        if support_steps > 0:
            # Never-observed voxels below an obstacle (``unobserved_below_obstacle``): one top-down
            # pass per (i, j) column; an observed obstacle voxel arms a budget of ``support_steps``
            # voxels that the never-observed voxels under it use up (the shadow fill's voxels pass
            # without re-arming: a guess does not extend a guess), anything observed that is not
            # an obstacle (free space, the floor) disarms it.
            # Every column (the production pass visits only those with an observed obstacle voxel).
            for i in range(nx):
                for j in range(ny):
                    run = 0
                    grp = 0
                    base = (i * ny + j) * nz
                    for k in range(nz - 1, -1, -1):
                        f = base + k
                        if state[f] == 3 and g[f] != _FREE and g[f] != 0:
                            run, grp = support_steps, g[f]
                        elif filled[f]:
                            continue
                        elif state[f] == 2 and run > 0:
                            filled[f] = True
                            g[f] = grp
                            cand[n_marked] = f
                            n_marked += 1
                            run -= 1
                        elif state[f] != 2:
                            run = 0
        # Close the pinholes the diverging marches leave, voxel by voxel.
        n_filled = close_pinholes_by_voxel(state, filled, g, cand, n_marked, shape)
        for m in range(n_filled):
            state[cand[m]] = 3
    for f in range(n):  # every voxel (the production's only those the wavefront reached, without unknown_group)
        if g[f] == _FREE:
            g[f] = 0
        elif unknown_group > 0 and state[f] == 2 and w[f] <= 0.0:
            g[f] = unknown_group


def close_pinholes_by_voxel(state: np.ndarray, filled: np.ndarray, g: np.ndarray, cand: np.ndarray, n_marked: int,
                            shape: np.ndarray) -> int:
    """The production's ``_close_pinholes`` voxel by voxel: both passes look around every filled
    voxel (``cand[:n_marked]`` and what the first pass closed), each voxel's six neighbours."""
    nx, ny, nz = (int(x) for x in shape)
    sy, sx = nz, ny * nz
    n_filled = n_marked
    for _ in range(2):
        n_old = n_filled
        for m in range(n_old):
            f0 = cand[m]
            k0 = f0 % nz
            j0 = (f0 // nz) % ny
            i0 = f0 // sx
            for a in range(6):  # +i, -i, +j, -j, +k, -k
                i = i0 + (1 if a == 0 else -1 if a == 1 else 0)
                j = j0 + (1 if a == 2 else -1 if a == 3 else 0)
                k = k0 + (1 if a == 4 else -1 if a == 5 else 0)
                if i < 0 or i >= nx or j < 0 or j >= ny or k < 0 or k >= nz:
                    continue
                f = (i * ny + j) * nz + k
                if state[f] != 2 or filled[f]:
                    continue
                if 0 < i < nx - 1 and _solid_at(f - sx, state, filled, g) and _solid_at(f + sx, state, filled, g):
                    g[f] = g[f - sx]
                elif 0 < j < ny - 1 and _solid_at(f - sy, state, filled, g) and _solid_at(f + sy, state, filled, g):
                    g[f] = g[f - sy]
                elif 0 < k < nz - 1 and _solid_at(f - 1, state, filled, g) and _solid_at(f + 1, state, filled, g):
                    g[f] = g[f - 1]
                else:
                    continue
                state[f] = 4  # closed in this pass: counted as solid from the next pass on
                cand[n_filled] = f
                n_filled += 1
        for m in range(n_old, n_filled):
            filled[cand[m]] = True
            state[cand[m]] = 2
    return n_filled
