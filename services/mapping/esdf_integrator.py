"""Semantic occupancy → semantically inflated signed ESDF (Algorithm 1, lines 3–12).

**Distance convention.** An occupied voxel is the cube it covers; the obstacle set of a
risk group g is the union of its cubes, O_g. From the Euclidean distance transform between
voxel centres (``distance_transform``: exact, compiled, multi-threaded) the signed distance to O_g is

    s_g(x) =  e_g(x) − v/2        outside O_g, e_g = distance to the nearest centre in O_g,
    s_g(x) = −(e_f(x) − v/2)      inside,      e_f = distance to the nearest unoccupied centre,

(v the voxel size): exact along the grid axes, so an occupied voxel is negative (−v/2 on a
one-voxel shell) and its free neighbour positive (+v/2). For the thin shells the TSDF's
surface support produces, this never over-estimates the distance to the true surface (the
surface runs inside the cubes); for solid voxelised shapes it is within half a voxel.

**Exact inflation (default).** The inflated set of group g is the Minkowski sum of O_g with
a ball of radius m_g (the group's margin). Outside O_g the signed distance to it is
s_g − m_g, so the semantically inflated field is

    d(x) = min_g ( s_g(x) − m_g ),        risk_group(x) = argmin_g,

margins exact in metres (never rounded to voxels). Ties go to the lower group id (higher
risk, by the config's order), except that the base group L below yields every tie.

Cost: with m_min the smallest margin among the groups present and L the largest group having
it, d = min( s_U − m_min, min_{g≠L} (s_g − m_g) ) where s_U is the signed distance to the
union of all groups (for the group L term this is exact; for any other group the term it
replaces is dominated by that group's own). So one full-grid EDT of the union, plus one EDT
per *other* group on a box around it: group g can only win where e_g − m_g ≤ e_U − m_min and
e_g − v/2 − m_g < max_distance, and the distance to g's bounding box is a lower bound of e_g,
so the box only has to hold the voxels whose distance to that bounding box passes both tests.
People, pets and furniture cost little; walls (no margin) ride on the union.
The inside depth e_f is one voxel for every occupied voxel with a free face neighbour; only
deeper voxels need an EDT. Solid obstacles are deep almost everywhere; then the two transforms
of the whole grid (to the occupied and to the free voxels) yield e_U and e_f together.

**Paper-faithful variant** (``inflation = "dilate"``): each group's occupancy is dilated by
a ball of round(m_g / v) voxels, then the ESDF of the union is taken with no further margin
(the nearest inflated voxel names the group). Margins are thus rounded to whole voxels; kept
for the benchmark's comparison.

Finally d is clipped to [−max_distance, max_distance]; where d = max_distance no obstacle is
within range and the risk group is 0.

**Incremental 3-D updates** (``update``): ``esdf_incremental = "box"`` (default) recomputes the box
the changed voxels can reach, exactly; ``"wave"`` moves only the voxels whose value changes, by
nearest-site wavefronts over a margin-weighted obstacle map and a free-space map (``esdf_wave``),
equal to this module's field up to rare digital misses of 26-neighbour propagation (see there).

**2-D slice for ground robots.** The slice at (x, y) is the minimum over the height band
[z_lo, z_hi] of the 3-D signed distance to the obstacles *inside* the band (floor and
ceiling obstacles outside the band are excluded). Because for such an obstacle the minimum
over z of sqrt(Δxy² + Δz²) is Δxy (take z at the obstacle's height), that minimum equals
the 2-D distance to the band's obstacles projected onto the floor plane: the slice is
computed exactly and cheaply with 2-D EDTs of the projected per-group occupancy.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from ..runtime.jit import threads
from . import distance_transform
from .config import EsdfParams, MapperConfig
from .esdf_wave import WaveEsdf


def _bbox(mask: np.ndarray, pad: int) -> tuple[slice, ...] | None:
    """Bounding box of the True voxels grown by ``pad``, clipped to the array; None when empty."""
    out = []
    for a in range(mask.ndim):
        other = tuple(b for b in range(mask.ndim) if b != a)
        idx = np.flatnonzero(mask.any(axis=other)) if other else np.flatnonzero(mask)
        if idx.size == 0:
            return None
        out.append(slice(max(int(idx[0]) - pad, 0), min(int(idx[-1]) + pad + 1, mask.shape[a])))
    return tuple(out)


def _grow(box: tuple[slice, ...], pad: int, shape: tuple[int, ...]) -> tuple[slice, ...]:
    return tuple(slice(max(s.start - pad, 0), min(s.stop + pad, n)) for s, n in zip(box, shape, strict=True))


def _ball(radius: int, ndim: int) -> np.ndarray:
    r = np.arange(-radius, radius + 1)
    grids = np.meshgrid(*([r] * ndim), indexing="ij")
    return sum(g.astype(np.int64) ** 2 for g in grids) <= radius * radius


class EsdfIntegrator:
    """Builds the signed, semantically inflated distance field (see the module docstring)."""

    def __init__(self, params: EsdfParams, voxel_size: float):
        self.config, self.voxel_size = params, voxel_size
        self._wave: WaveEsdf | None = None  # the wavefront maps, made by the first ``update``

    @classmethod
    def of(cls, config: MapperConfig) -> EsdfIntegrator:
        """Wired from a whole mapper configuration: its ``EsdfParams`` and the volume's voxel size."""
        return cls(config.part(EsdfParams), config.voxel_size)

    # -- the two public forms ---------------------------------------------------------------
    def compute(self, groups: np.ndarray, margins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """3-D field from the per-voxel obstacle group map; returns (distance f4, risk_group u1)."""
        return self._field3d(groups, margins)

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the 3-D passes before serving: on a small grid whose
        group boxes are parts of it (strided views) and one where a box is all of it."""
        distance_transform.edt(np.eye(3, dtype=bool)[:, :, None], 1.0, self.config.threads)
        margins = np.array([0.0, 0.1, 0.0])
        groups = np.zeros((24, 24, 24), np.uint8)
        groups[:, :, 0:4] = 2  # deep base group
        groups[2, 2, 6] = 1
        self._field3d(groups, margins)
        self._field3d(np.ones((2, 2, 2), np.uint8), np.array([0.0, 0.1]))
        groups[:] = 0
        groups[0, 0, 0], groups[-1, -1, -1] = 1, 2
        self._field3d(groups, margins)
        if self.config.esdf_incremental == "wave":  # compile the wave kernels (a scratch instance)
            wave = WaveEsdf(self.voxel_size, self.config.max_distance)
            wave.update(groups, margins)
            groups[3:6, 3:6, 3:6] = 1
            wave.update(groups, margins)
            wave.shift(np.array([1, 0, -1]))

    def shift(self, delta: np.ndarray) -> None:
        """The volume moved by ``delta`` voxels (``Volume.shift_to``): the wave's maps move with it."""
        if self._wave is not None:
            self._wave.shift(delta)

    def _wave_esdf(self) -> WaveEsdf:
        if self._wave is None:
            self._wave = WaveEsdf(self.voxel_size, self.config.max_distance)
        return self._wave

    def update(self, groups: np.ndarray, margins: np.ndarray, previous_groups: np.ndarray,
               previous: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, int]:
        """The 3-D field after an edit, recomputing only where it can have changed.

        With ``esdf_incremental = "wave"`` (exact inflation, the default) the wavefront maps of
        ``esdf_wave`` do it: they keep the last group map they saw, so ``previous_groups`` and
        ``previous`` are not read; the cost follows the voxels whose value changes. Else (``box``):
        ``previous`` = (distance, risk_group) was computed by ``compute`` (or ``update``) from
        ``previous_groups`` with the same margins and configuration. The voxels whose group changed
        (occupancy or labels) have a bounding box; a voxel farther than the reach
        ρ = max_distance + max margin + v from every changed voxel keeps its value (its clipped
        distance, its inside depth and its nearest group are decided within ρ). The box grown by
        ρ is recomputed, from the groups in the box grown by 2ρ (all that decides its values), the
        rest is copied. The result equals ``compute(groups, margins)`` (the test oracle): the
        same base group is used, and the sub-box EDTs see every voxel that matters. Returns
        (distance, risk_group, voxels recomputed).
        """
        c = self.config
        if c.esdf_incremental == "wave" and c.inflation == "exact" and groups.ndim == 3:
            return self._wave_esdf().update(groups, margins)
        return self.update_box(groups, margins, previous_groups, previous)

    def update_box(self, groups: np.ndarray, margins: np.ndarray, previous_groups: np.ndarray,
                   previous: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, int]:
        """``update`` by a recompute of the changed voxels' box grown by the reach (see ``update``)."""
        c = self.config
        if groups.ndim == 3 and groups.shape == previous_groups.shape:
            from . import esdf_kernels as k

            with threads(c.threads):
                lo, hi = k.diff_box(np.ascontiguousarray(groups, dtype=np.uint8),
                                    np.ascontiguousarray(previous_groups, dtype=np.uint8))
            box = tuple(slice(int(a), int(b)) for a, b in zip(lo, hi, strict=True)) if hi[0] > lo[0] else None
        else:
            box = _bbox(groups != previous_groups, 0)
        if box is None:
            return previous[0].copy(), previous[1].copy(), 0
        n_groups, v = margins.shape[0] - 1, self.voxel_size
        reach = math.ceil((c.max_distance + float(np.max(margins[1:], initial=0.0)) + v) / v) + 1
        if c.inflation == "dilate":
            reach += max(round(float(m) / v) for m in margins[1:]) if n_groups else 0
        out_box = _grow(box, reach, groups.shape)
        in_box = _grow(box, 2 * reach, groups.shape)
        if all(s.start == 0 and s.stop == n for s, n in zip(in_box, groups.shape, strict=True)):
            dist, grp = self.compute(groups, margins)
            return dist, grp, groups.size
        counts = np.bincount(groups.ravel(), minlength=n_groups + 1)
        sub = groups[in_box]
        d_sub, g_sub = self._field3d(sub, margins, counts=counts)
        inner = tuple(slice(o.start - i.start, o.stop - i.start) for o, i in zip(out_box, in_box, strict=True))
        dist, grp = previous[0].copy(), previous[1].copy()
        dist[out_box] = d_sub[inner]
        grp[out_box] = g_sub[inner]
        return dist, grp, math.prod(s.stop - s.start for s in out_box)

    def compute_slice(self, groups: np.ndarray, k_lo: int, k_hi: int,
                      margins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """2-D slice over the z-voxels [k_lo, k_hi) of the band; shapes (nx, ny, 1)."""
        k_lo, k_hi = max(k_lo, 0), min(k_hi, groups.shape[2])
        masks: dict[int, np.ndarray] = {}
        if k_hi > k_lo:
            band = groups[:, :, k_lo:k_hi]
            masks = {g: m.any(axis=2) for g, m in self._masks(band, margins.shape[0] - 1).items()}
        dist, grp = self._field(masks, margins, shape=groups.shape[:2])
        return dist[:, :, None], grp[:, :, None]

    # -- internals ------------------------------------------------------------------------------
    def _field3d(self, groups: np.ndarray, margins: np.ndarray,
                 counts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The 3-D field of a group map by the compiled kernels (``esdf_kernels``) under exact
        inflation; else by ``_field``. The same steps and float32 arithmetic as ``_field``."""
        c = self.config
        n_groups = margins.shape[0] - 1
        if c.inflation != "exact" or groups.ndim != 3:
            return self._field(self._masks(groups, n_groups), margins, shape=groups.shape, counts=counts)
        with threads(c.threads):  # the passes' parallel loops, as the EDTs'
            return self._field3d_compiled(groups, margins, counts)

    def _field3d_compiled(self, groups: np.ndarray, margins: np.ndarray,
                          counts: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        from . import esdf_kernels as k

        c = self.config
        n_groups = margins.shape[0] - 1
        v, dmax = self.voxel_size, c.max_distance
        groups = np.ascontiguousarray(groups, dtype=np.uint8)
        if not groups.flags.writeable:  # one compiled signature (numba types read-only arrays apart)
            groups = groups.copy()
        if int(groups.max(initial=0)) > n_groups:
            groups = np.where(groups > n_groups, 0, groups).astype(np.uint8)  # as _masks: unknown ids are free
        local, lo, hi, depth = k.scan(groups, n_groups, np.float32(v))
        present = [g for g in range(1, n_groups + 1) if local[g] > 0]
        if not present:
            return np.full(groups.shape, dmax, dtype=np.float32), np.zeros(groups.shape, dtype=np.uint8)
        m_min = min(float(margins[g]) for g in present)
        size = local if counts is None else counts
        base = max((g for g in present if float(margins[g]) == m_min), key=lambda g: (int(size[g]), -g))
        occupied = (lo[1:n_groups + 1].min(axis=0), hi[1:n_groups + 1].max(axis=0))  # empty groups: lo > hi
        if hi[n_groups + 1, 0] >= 0:  # deep voxels: their depth needs an EDT (see _deep_depth)
            self._deep_depth(groups, depth, lo[n_groups + 1], hi[n_groups + 1], occupied)
        e = self._edt_of_label(groups, 0, equal=False, site_box=occupied)  # to the nearest occupied voxel
        half = np.float32(0.5 * v)
        dist = k.base_term(groups, depth, e, base, half, np.float32(m_min))
        grp = np.full(groups.shape, base, dtype=np.uint8)
        for g in sorted(present, reverse=True):
            if g == base:
                continue
            m_g = float(margins[g])
            far = dmax + m_g + 0.5 * v
            pad = math.ceil(far / v) + 1
            llo = np.maximum(lo[g] - pad, 0)
            lhi = np.minimum(hi[g] + pad + 1, np.asarray(groups.shape))
            blo, bhi = k.reach_box(e, lo[g], hi[g], llo, lhi, np.float32(m_g - m_min), np.float32(far),
                                   np.float32(v))
            box = tuple(slice(int(a), int(b)) for a, b in zip(blo, bhi, strict=True))
            sub = groups[box]
            s = self._edt_of_label(sub, g, equal=True, site_box=(lo[g] - blo, hi[g] - blo))
            k.combine((sub, depth[box], s, dist[box], grp[box]), g, base,
                      (half, np.float32(m_g), np.float32(0.5 * v + m_g)))
        k.clip(dist, grp, np.float32(dmax))
        return dist, grp

    def _deep_depth(self, groups: np.ndarray, depth: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                    occupied: tuple[np.ndarray, np.ndarray]) -> None:
        """Fill the depth of the deep voxels (marked −1 in ``depth``, bounding box [lo, hi]) in place:
        the distance to the nearest free voxel, by ``distance_transform.inside_depth`` over the
        occupied voxels' box (``occupied``), whose cost follows the occupied voxels."""
        distance_transform.inside_depth(groups, depth, occupied[0], occupied[1], self.voxel_size, self.config.threads)

    @staticmethod
    def _masks(groups: np.ndarray, n_groups: int) -> dict[int, np.ndarray]:
        counts = np.bincount(groups.ravel(), minlength=n_groups + 1)
        return {g: groups == g for g in range(1, min(len(counts), n_groups + 1)) if counts[g] > 0}

    def _edt(self, sites: np.ndarray) -> np.ndarray:
        """Distance (m, float32) from every voxel to the nearest True voxel of ``sites`` (0 there)."""
        return distance_transform.edt(sites, self.voxel_size, self.config.threads)

    def _edt_of_label(self, labels: np.ndarray, label: int, equal: bool,
                      site_box: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """``_edt`` of the sites (labels == label) == equal of a uint8 group map or a box of it;
        ``site_box`` (inclusive lo, hi) bounds where the sites are (``distance_transform.edt_of_label``)."""
        return distance_transform.edt_of_label(labels, label, equal, self.voxel_size, self.config.threads, site_box)

    def _edt_two_sided(self, union: np.ndarray) -> np.ndarray:
        """Distance from each voxel to the nearest voxel on the other side of ``union`` (occupied ↔
        free): the sum of two transforms (each is 0 on its own sites, so one of the two terms is 0
        everywhere)."""
        e = self._edt(union)
        e += self._edt(~union)
        return e

    def _field(self, masks: dict[int, np.ndarray], margins: np.ndarray, shape: tuple[int, ...],
               counts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``counts``: voxels per group of the whole grid when ``masks`` cover a part of it (the base
        group is chosen by them, so a part computes what the whole does)."""
        c = self.config
        v, dmax = self.voxel_size, c.max_distance
        # Group sizes before any dilation: the counts a part is given are the whole grid's groups,
        # so the whole must choose its base group by the same numbers.
        sizes = {g: int(m.sum()) for g, m in masks.items()} if counts is None else None
        if c.inflation == "dilate":
            masks, margins = self._dilate(masks, margins), np.zeros_like(margins)
        if not masks:
            return np.full(shape, dmax, dtype=np.float32), np.zeros(shape, dtype=np.uint8)
        union = np.zeros(shape, dtype=bool)
        for m in masks.values():
            union |= m
        depth, dist = self._inside(union)
        # The base term: the union's signed distance less the smallest margin stands for the
        # group L with that margin (the largest such group, usually walls and structure).
        m_min = min(float(margins[g]) for g in masks)
        size = sizes.__getitem__ if sizes is not None else (lambda g: int(counts[g]))
        base = max((g for g in masks if float(margins[g]) == m_min), key=lambda g: (size(g), -g))
        if dist is None:
            dist = self._edt(union)
        e_union = dist.copy()
        dist -= np.float32(0.5 * v + m_min)
        dist[union] = -(depth[union] - np.float32(0.5 * v)) - np.float32(m_min)
        dist[union & ~masks[base]] = np.inf  # inside another group, that group's own term decides
        grp = np.full(shape, base, dtype=np.uint8)
        for g in sorted(masks, reverse=True):
            if g == base:
                continue
            mask, m_g = masks[g], float(margins[g])
            box = self._reach(mask, e_union, m_g - m_min, dmax + m_g + 0.5 * v)
            if box is None:
                continue
            sub = mask[box]
            s = self._edt(sub)
            s -= np.float32(0.5 * v + m_g)
            s[sub] = -(depth[box][sub] - np.float32(0.5 * v)) - np.float32(m_g)
            cur, cur_g = dist[box], grp[box]
            better = (s < cur) | ((s == cur) & ((cur_g == base) | (g < cur_g)))
            cur[better] = s[better]
            cur_g[better] = g
        clipped = dist >= dmax
        dist[clipped] = dmax
        grp[clipped] = 0
        np.maximum(dist, -dmax, out=dist)
        return dist, grp

    def _reach(self, mask: np.ndarray, e_union: np.ndarray, slack: float,
               far: float) -> tuple[slice, ...] | None:
        """The box where a group's term can still win: its bounding box grown to every voxel whose
        distance to that box is within ``slack`` of the union's distance and below ``far``.

        The distance to the box is a lower bound of the distance to the group, so outside this
        region the group's term is no smaller than the union term (or is clipped).
        """
        v = self.voxel_size
        tight = _bbox(mask, 0)
        if tight is None:
            return None
        loose = _bbox(mask, math.ceil(far / v) + 1)
        assert loose is not None
        axes = []
        for a, (t, lo) in enumerate(zip(tight, loose, strict=True)):
            idx = np.arange(lo.start, lo.stop)
            gap = np.maximum(np.maximum(t.start - idx, idx - (t.stop - 1)), 0).astype(np.float32) * np.float32(v)
            shape = [1] * mask.ndim
            shape[a] = gap.size
            axes.append((gap * gap).reshape(shape))
        b2 = sum(axes[1:], axes[0])
        limit = np.minimum(e_union[loose] + np.float32(slack), np.float32(far))
        near = b2 <= limit * limit
        box = _bbox(near, 0)
        assert box is not None  # the group's own voxels are always near
        return tuple(slice(lo.start + b.start, lo.start + b.stop) for lo, b in zip(loose, box, strict=True))

    def _inside(self, union: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Distance from each occupied voxel to the nearest unoccupied centre (0 elsewhere), and
        the outside distance e_U (0 on occupied voxels) when it came for free, else None.

        An occupied voxel with a free face neighbour is exactly one voxel deep; only the rest
        needs an EDT, on their bounding box grown by the clip depth — no free voxel within it
        means deeper than the clip (inf). Solid obstacles (walls, filled interiors) have deep
        voxels everywhere, so that box is most of the grid: then the two-sided transform of the
        whole grid (``_edt_two_sided``) gives both sides at once.
        """
        c = self.config
        depth = np.zeros(union.shape, dtype=np.float32)
        box = _bbox(union, 0)
        if box is None:
            return depth, None
        sub = union[box]
        exposed = np.zeros(sub.shape, dtype=bool)
        for a in range(sub.ndim):
            lo = [slice(None)] * sub.ndim
            hi = [slice(None)] * sub.ndim
            lo[a], hi[a] = slice(0, -1), slice(1, None)
            exposed[tuple(lo)] |= ~sub[tuple(hi)]
            exposed[tuple(hi)] |= ~sub[tuple(lo)]
        # Free voxels just outside the bounding box (but inside the grid) are neighbours too.
        for a in range(sub.ndim):
            for side, edge in ((0, box[a].start - 1), (-1, box[a].stop)):
                if 0 <= edge < union.shape[a]:
                    outer = list(box)
                    outer[a] = slice(edge, edge + 1)
                    face = [slice(None)] * sub.ndim
                    face[a] = slice(side, side + 1) if side == 0 else slice(-1, None)
                    exposed[tuple(face)] |= ~union[tuple(outer)]
        exposed &= sub
        depth[box] = np.where(exposed, np.float32(self.voxel_size), np.float32(0.0))
        deep = sub & ~exposed
        if not deep.any():
            return depth, None
        deep_full = np.zeros(union.shape, dtype=bool)
        deep_full[box] = deep
        dbox = _bbox(deep_full, math.ceil((c.max_distance + self.voxel_size) / self.voxel_size) + 1)
        assert dbox is not None
        if math.prod(s.stop - s.start for s in dbox) > union.size // 2:
            both = self._edt_two_sided(union)
            depth[deep_full] = both[deep_full]
            both[union] = 0.0
            return depth, both
        e = self._edt(~union[dbox])
        d = depth[dbox]
        d[deep_full[dbox]] = e[deep_full[dbox]]
        return depth, None

    def _dilate(self, masks: dict[int, np.ndarray], margins: np.ndarray) -> dict[int, np.ndarray]:
        """The paper's voxel inflation: each group's occupancy dilated by round(m_g / v) voxels."""
        out = {}
        for g, mask in masks.items():
            r = round(float(margins[g]) / self.voxel_size)
            if r <= 0:
                out[g] = mask
                continue
            box = _bbox(mask, r)
            grown = np.zeros_like(mask)
            if box is not None:
                grown[box] = ndimage.binary_dilation(mask[box], structure=_ball(r, mask.ndim))
            out[g] = grown
        return out
