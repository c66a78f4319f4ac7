"""TSDF + semantic labels → solid semantic occupancy (the paper's O and Ψ(O, S)).

**Surface.** A voxel *supports the surface* when

    weight ≥ min_weight,   |tsdf| ≤ surface_band,   and it holds a fused label ℓ,

and its obstacle *risk group* is the risk config's ``label_to_group()[ℓ]``. Labels outside the
obstacle set (``free_labels``: floor, ceiling, …) map to group 0 and are dropped, exactly the
filtering step of Algorithm 1. The label condition means some pixel saw a surface in this very
voxel (labels are voted in the same band): it removes the spurious zero crossings a TSDF grows
just behind object edges, where the negative band of one surface averages with the free space
seen past the edge.

**Solid interior** (``obstacle_interior = "solid"``, the default). A voxel observed *behind* a
surface,

    weight ≥ min_weight   and   tsdf < −surface_band   (or a labelled surface voxel),

belongs to the obstacle (unlabelled voxels within the band stay out, for the reason above), as
voxblox (``EsdfIntegrator::updateFromTsdfBlocks``: the sign of the TSDF is the ESDF's side) and
nvblox (``markAllSitesKernel`` in ``esdf_integrator.cu``: weight ≥ min_weight and distance ≤ 0
is ``is_inside``) treat it. Such a voxel carries no label of its own (labels are voted only
within the surface band), so it takes the label of its nearest labelled surface voxel: a
6-connected wavefront from every labelled surface voxel through the observed interior
(city-block nearest; ties go to the higher-risk group, and an obstacle beats a free label). So
the floor's underside stays free (it reaches the floor label first) while the inside of a person
is the person's group, and the class margin is applied to the whole solid obstacle. Interior
voxels that no labelled surface reaches (isolated noise) stay free. Beside an edge seen
obliquely, the rays that hit the edge carry their negative band (τ along the ray) up to
τ·sin θ past the silhouette; those voxels join the obstacle too (as in voxblox and nvblox),
which errs towards the obstacle.

**Never-observed space behind surfaces** (``unobserved_behind_surface``). The TSDF is negative
only within the truncation τ behind a surface, so a thin-shelled observation (one side seen)
leaves the rest of an object's inside never observed (weight < min_weight):

* ``"free"``: it stays free space; the solid is only τ deep and, deeper inside, the field is
  positive again with a gradient pointing further in — a look-ahead point that overshoots the
  band sees free space.
* ``"solid"`` (default): never-observed voxels up to ``behind_surface_depth`` D behind the
  observed interior of an obstacle join it (same group). The TSDF layer keeps, for every voxel
  seen behind a surface, the direction u of the (last) ray that saw it so. From every such voxel
  of an obstacle group that borders never-observed space, a march of length D goes on along u:
  into the shadow the surface casts, along the viewing direction.
  The march only marks never-observed voxels; observed free space or a free-labelled surface
  (the floor) ends it, so the fill never enters space seen free, and never grows sideways or
  towards the camera where the view simply ended (an isotropic fill, or one along −∇tsdf, which
  the free space seen past an edge or the floor at an object's foot tilts, would grow obstacles
  out of the field of view towards the robot). Each march marks every voxel its segment crosses;
  the pinholes left between diverging marches are closed (twice: a never-observed voxel between
  two obstacle voxels along an axis). The never-seen back of an object is thus resolved to
  about a voxel and a half.

The default D = 5 m spans the default map: the shadow an observed obstacle casts is solid up to
the first observed voxel (or the map's edge), so the inside of an obstacle reads negative however
deep, also where only one face was seen — a 1.2 m sofa seen end-on is negative 0.3, 0.8 and 1.1 m
inside, its gradient pointing out of the shadow (back to the seen face, up or sideways: wherever
observed or unshadowed space is nearest), never further in along the line of sight. A bounded fill
(0.5 m, say) leaves the inside free again past τ + D, with the gradient pointing
further in: a look-ahead point that overshot the fill was pushed deeper. The trade-off: the fill
also closes the never-observed space behind an obstacle — the part of a doorway hidden behind its
jamb, the floor behind a sofa, the space behind a thin pole — until a camera looks into it; the
free space carved by any ray through it reopens it at once (observed voxels stop the fill). A
camera that drives towards what it sees looks into that space before the robot gets there.
``"free"`` keeps every unseen gap open but leaves obstacles only τ deep.

**Never-observed space below obstacles** (``unobserved_below_obstacle``, default ``"solid"``).
A camera above an object's top sees the top at a grazing angle: the viewing direction is
nearly horizontal, so the march above fills only a few centimetres under the top, and a side
that no frame faces (a bed's long side seen from the room's centre only) leaves the object
hollow below a thin lid — in the benchmark a bed read +0.075 m at 0.2 m height, 0.2 m inside
it. Objects rest on something: never-observed voxels straight below an observed obstacle voxel
(the shadow fill's voxels do not extend it), up to ``below_obstacle_depth`` (default 1 m), join it (same group). Any
observed voxel below ends the column (free space seen under a table keeps it open, the floor
stops it); only never-observed space under an obstacle is filled — the space under a table
that no ray ever crossed reads solid until a camera looks under it. ``"free"`` leaves it free.

**Unknown space.** With ``unknown_is_occupied`` every never-observed voxel (weight 0) that the
fill did not claim is also an obstacle, of the ``unknown_group``.

Cost: two passes over the grid, and work in proportion to the obstacle voxels (the wavefront, the
marches from the interior's border and the closing around the filled voxels: the passes after
the wavefront visit only the columns, neighbours and voxels these can change; the whole-volume
scans are the tests' oracle, ``tests/oracles/occupancy.py``); about 2 ms for the benchmark room in
101³ voxels.

``obstacle_interior = "shell"`` occupies only the surface band: the inside of an obstacle reads as
free space.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..runtime.jit import jit
from .layers import NO_LABEL, SemanticLayer, TsdfLayer
from .raycast import ray_voxels

_FREE = 255
"""Internal group mark of a voxel that belongs to a free-labelled surface (floor, ceiling)."""


def surface_support(tsdf: TsdfLayer, min_weight: float, surface_band: float) -> np.ndarray:
    """Boolean mask of the voxels on the fused surface."""
    return (tsdf.weight >= max(min_weight, 1e-12)) & (np.abs(tsdf.tsdf) <= surface_band)


@jit
def _enqueue_by_priority(cand: np.ndarray, n_cand: int, g: np.ndarray, queue: np.ndarray) -> int:
    """Counting sort of the candidate voxels by group id (1 = highest risk first, ``_FREE`` last)
    into ``queue``: a FIFO wavefront then hands every tie to the earlier (riskier) group."""
    counts = np.zeros(257, np.int64)
    for m in range(n_cand):
        counts[g[cand[m]] + 1] += 1
    for b in range(1, 257):
        counts[b] += counts[b - 1]
    for m in range(n_cand):
        f = cand[m]
        queue[counts[g[f]]] = f
        counts[g[f]] += 1
    return n_cand


_DEBRUIJN = np.uint64(0x03F79D71B4CB0A89)
"""A de Bruijn sequence B(2, 6): ``(b * _DEBRUIJN) >> 58`` differs for each single-bit word b."""
_BIT_OF = np.zeros(64, np.int64)
for _b in range(64):  # the table inverts that map, so it is derived here rather than written out
    _BIT_OF[((1 << _b) * int(_DEBRUIJN) % (1 << 64)) >> 58] = _b


@jit
def _close_pinholes(state: np.ndarray, filled: np.ndarray, g: np.ndarray, cand: np.ndarray, n_marked: int,
                    shape: np.ndarray) -> int:
    """Close the pinholes the diverging marches leave, twice: a never-observed voxel beside a
    filled voxel, between two obstacle voxels (filled, or observed interior / surface of an obstacle
    group) along an axis, takes the group of the lower-index one on the first such axis (i, j, k).
    A voxel closed in a pass counts as solid, and as filled, from the next pass on, so a pass's
    result does not depend on the order it visits voxels in; the second pass looks only beside the
    voxels the first one closed. ``cand[:n_marked]`` lists the filled voxels; the closed ones are
    appended. Returns the new count.

    The passes run on bit planes, 64 voxels of a column to a word: per voxel, the pass over the
    filled voxels' neighbours cost three times the whole march on the benchmark's maps (8 of 11 ms,
    ~10⁵ filled voxels), and it is a few word operations per column here. The whole-volume scan in
    ``tests/oracles/occupancy.py`` is the reference it must equal."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    words = (nz + 63) >> 6
    nc = nx * ny
    solid = np.zeros((nc, words), np.uint64)
    hole = np.zeros((nc, words), np.uint64)  # never observed and not filled: what a pass may close
    near = np.zeros((nc, words), np.uint64)  # the voxels whose neighbours a pass looks at
    closed = np.zeros((nc, words), np.uint64)
    one, top = np.uint64(1), np.uint64(63)
    for c in range(nc):
        f = c * nz
        for k in range(nz):
            b = one << np.uint64(k & 63)
            if filled[f]:
                solid[c, k >> 6] |= b
                near[c, k >> 6] |= b
            elif state[f] == 2:
                hole[c, k >> 6] |= b
            elif state[f] == 3 and g[f] != _FREE and g[f] != 0:
                solid[c, k >> 6] |= b
            f += 1
    sy, sx = nz, ny * nz
    n_filled = n_marked
    for _ in range(2):
        for i in range(nx):
            for j in range(ny):
                c = i * ny + j
                for w in range(words):
                    h = hole[c, w]
                    if h == 0:
                        continue
                    # beside a voxel of ``near``: along k within the column (bits carried across
                    # words), along i and j in the neighbouring columns
                    a = near[c, w]
                    a = (a << one) | (a >> one)
                    if w > 0:
                        a |= near[c, w - 1] >> top
                    if w < words - 1:
                        a |= near[c, w + 1] << top
                    if i > 0:
                        a |= near[c - ny, w]
                    if i < nx - 1:
                        a |= near[c + ny, w]
                    if j > 0:
                        a |= near[c - 1, w]
                    if j < ny - 1:
                        a |= near[c + 1, w]
                    h &= a
                    if h == 0:
                        continue
                    s = solid[c, w]
                    below, above = s << one, s >> one  # bit k: solid at k − 1, at k + 1
                    if w > 0:
                        below |= solid[c, w - 1] >> top
                    if w < words - 1:
                        above |= solid[c, w + 1] << top
                    pi = solid[c - ny, w] & solid[c + ny, w] if 0 < i < nx - 1 else np.uint64(0)
                    pj = solid[c - 1, w] & solid[c + 1, w] if 0 < j < ny - 1 else np.uint64(0)
                    h &= pi | pj | (below & above)
                    closed[c, w] = h
                    while h != 0:
                        low = h & (~h + one)  # the lowest set bit
                        f = c * nz + w * 64 + _BIT_OF[(low * _DEBRUIJN) >> np.uint64(58)]
                        if pi & low:
                            g[f] = g[f - sx]
                        elif pj & low:
                            g[f] = g[f - sy]
                        else:
                            g[f] = g[f - 1]
                        cand[n_filled] = f
                        n_filled += 1
                        h ^= low
        for c in range(nc):
            for w in range(words):
                h = closed[c, w]
                near[c, w] = h
                if h != 0:
                    solid[c, w] |= h
                    hole[c, w] &= ~h
                    closed[c, w] = 0
    for m in range(n_marked, n_filled):
        filled[cand[m]] = True
    return n_filled


@jit
def _solid(layers: tuple, lut: np.ndarray, rule: tuple, groups: np.ndarray) -> None:
    """Fill ``groups`` (all zero on entry) with the solid semantic occupancy of ``layers`` = (tsdf,
    weight, view, label); see the module docstring. ``rule`` = (min_w, band, fill_steps,
    unknown_group, support_steps), as ``OccupancyRule``'s.

    Sparse: the support pass visits only the (i, j) columns holding an observed obstacle voxel,
    the pinhole passes run on bit planes (``_close_pinholes``), and the final pass visits only the
    voxels the wavefront reached (when ``unknown_group`` is 0) — the only ones these passes can
    change. The same passes over the whole volume are the tests' oracle
    (``tests/oracles/occupancy.py``), which gives the same result."""
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
            # Only a column with an observed obstacle voxel arms the budget; those voxels are in
            # the wavefront's queue (state 3 is set nowhere else before this pass).
            column = np.zeros(nx * ny, np.bool_)
            for m in range(tail):
                f = queue[m]
                if g[f] != _FREE and g[f] != 0:
                    column[f // nz] = True
            for i in range(nx):
                for j in range(ny):
                    if not column[i * ny + j]:
                        continue
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
        # Close the pinholes the diverging marches leave (``_close_pinholes``).
        n_filled = _close_pinholes(state, filled, g, cand, n_marked, shape)
        for m in range(n_filled):
            state[cand[m]] = 3
    if unknown_group <= 0:
        # The free mark is only ever set by the wavefront (fills and pinholes copy obstacle groups).
        for m in range(tail):
            f = queue[m]
            if g[f] == _FREE:
                g[f] = 0
        return
    for f in range(n):
        if g[f] == _FREE:
            g[f] = 0
        elif unknown_group > 0 and state[f] == 2 and w[f] <= 0.0:
            g[f] = unknown_group


class OccupancyRule(NamedTuple):
    """How ``semantic_occupancy`` decides: the surface support (``min_weight``, ``surface_band``),
    the interior, the fills and the unknown space's group (see ``semantic_occupancy``)."""

    min_weight: float
    surface_band: float
    unknown_group: int = 0
    interior: str = "solid"
    fill_steps: int = 0
    support_steps: int = 0


def semantic_occupancy(tsdf: TsdfLayer, semantic: SemanticLayer, label_to_group: np.ndarray,
                       rule: OccupancyRule) -> np.ndarray:
    """Per-voxel obstacle group (uint8, 1-based risk group id, 0 = not an obstacle) by ``rule``.

    ``interior``: ``"solid"`` (observed negative-TSDF voxels join the obstacle of their nearest
    labelled surface) or ``"shell"`` (the surface band only). ``fill_steps`` > 0 (solid only)
    also fills never-observed voxels up to that many voxel steps behind an obstacle's observed
    interior, and ``support_steps`` > 0 (with ``fill_steps`` > 0) never-observed voxels up to that
    many voxels straight below an observed obstacle voxel. ``unknown_group`` > 0 marks the remaining
    never-observed voxels as obstacles of that group.
    """
    min_weight, surface_band, unknown_group, interior = rule[:4]
    if interior == "solid":
        groups = np.zeros(tsdf.tsdf.shape, dtype=np.uint8)
        lut = np.ascontiguousarray(label_to_group, dtype=np.uint8)
        layers = (np.ascontiguousarray(tsdf.tsdf), np.ascontiguousarray(tsdf.weight), np.ascontiguousarray(tsdf.view),
                  np.ascontiguousarray(semantic.label))
        numbers = (float(max(min_weight, 1e-12)), float(surface_band), int(rule.fill_steps), int(unknown_group),
                   int(rule.support_steps))
        _solid(layers, lut, numbers, groups)
        return groups
    if interior != "shell":
        raise ValueError(f"interior {interior!r} is neither 'solid' nor 'shell'")
    occupied = surface_support(tsdf, min_weight, surface_band)
    occupied &= semantic.label != NO_LABEL
    groups = np.zeros(occupied.shape, dtype=np.uint8)
    groups[occupied] = label_to_group[semantic.label[occupied]]
    if unknown_group > 0:
        groups[tsdf.weight <= 0] = unknown_group
    return groups
