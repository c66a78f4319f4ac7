"""Tracked objects: the people and animals in the map, with velocities (``map/objects``).

After each map update, the mapper's semantic occupancy is cut into movable objects and each is
associated with a track across updates, whose velocity is estimated from the frames' stamps.

**Which voxels.** A voxel belongs to a movable object when it is occupied (the occupancy's risk
group > 0) in a group of a movable label (``dynamic_labels``, ADE20K names, default person and
animal), and its fused label is movable — or it has no label of its own (the solid interior
carries none; ``occupancy.py`` gives it the group of its nearest labelled surface). With the
TSDF at hand, only observed voxels count: the never-observed fill behind a surface reaches up to
``behind_surface_depth`` (5 m) into the shadow, which keeps the barrier conservative but is no
part of the person, whose centre and velocity it would drag away. Only parts that hold at least
one movable-labelled voxel become objects, so furniture and walls never do, whatever their group.

**2-D footprints.** Only the ESDF slice's height band (``band``, ``Mapper.band_indices``) is
looked at, projected onto the ground: a ground robot's barrier sees obstacles in that band, people
and animals move on the floor, and a footprint's centre is steadier than a 3-D centroid whose
height depends on how much of the body the camera saw. Footprint parts up to
``object_merge_gap`` apart are one object (a person's legs). An object's position is the centre of its
voxels in the band, each weighted by its inside fraction: 1 for the observed interior,
clip(½ − tsdf / voxel, 0, 1) for an observed surface voxel (the TSDF is the
distance to the surface, so this is the part of the voxel behind it). Counted whole, binary cells
put a centre anywhere within half a voxel of the truth along each axis, and a box whose edges lie
along the grid jumps by a whole row at once: over 5 maps at 10 Hz that alone is up to 0.15 m/s per
axis (the 5-sample slope's weights sum to 6 in absolute value over 0.1 s², times 2.5 cm), up to
0.2 m/s in norm for a box near an axis (found by random search). With the fractions, a box whose
sides the map holds is recovered within 0.025 m/s at any heading (same search).
The radius is the farthest cell centre from the position plus half a voxel.

**The trail.** The map keeps a walker's voxels a while after a frame last saw them
(``dynamic_moving_persist_s``, longer near a track: ``protected``), so a walker's footprint drags a
trail, and its whole centre moves slower than they do. Once a track moves, a footprint's columns
that its newest sighting did not see (older than it by more than ``object_fresh_s``) and that lie
behind the newest sighting's centre along the track's velocity are the trail: they leave the
position and the radius (the ESDF still holds them as an obstacle). A standing person's footprint
counts whole: a part the view has lost (its edge, an occluder) is no motion.

**Tracks.** A footprint continues the track of the same label whose constant-velocity prediction
is nearest, if it lies within ``object_gate`` + ``object_max_speed`` × (time since the track was
last seen) of the track's last position: no faster object can be farther. Pairs are taken
nearest first, one footprint per track; footprints left over start new tracks (ids are never
reused), tracks left over are not observed in this update: their ``age_ms`` grows and they are
dropped after ``object_expire_s``.

**Velocity.** The least-squares slope of the track's centres over the last ``object_window_s``
seconds, against the frames' stamps (never the wall clock), once the track has
``object_min_samples`` observations in the window (zero before; ``tracked_ms`` tells a consumer
how young a track is). Then bounded: capped at ``object_max_speed``, and zero below
``object_deadband``, so a static scene has ∂h/∂t = 0 (``tests/mapping/test_objects.py``: a
walking person-sized box within 0.15 m/s after 5 maps, a static scene at zero).

Pure core: no I/O; the mapping node calls ``ObjectTracker.update_map`` after each ESDF update and
publishes the result with the ESDF's header. The tracker reads the map only through ``MapReading``
(``Mapper.reading``), and gives back only ``protected``: the footprints the map's decay keeps.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import ndimage

from riskfield.protocol import TrackedObject

from ..runtime.jit import jit
from .config import DynamicParams, MapperConfig, ObjectParams
from .layers import NEVER, NO_LABEL

_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass
class Detection:
    """One movable object's footprint in one map update (world frame, metres)."""

    label: int
    position: np.ndarray  # (3,)
    radius: float
    cells: int
    #: when a current frame last saw a surface of it (the layers' ``hit`` clock, ms; None: unknown,
    #: e.g. no TSDF given, which counts as seen now)
    seen_ms: int | None = None
    #: its columns (world x, y), their inside fractions and whether the newest sighting missed each
    #: (module doc, the trail); None without ``hit`` times
    columns: np.ndarray | None = None
    inside: np.ndarray | None = None
    stale: np.ndarray | None = None
    voxel_size: float = 0.0

    def without_trail(self, velocity: np.ndarray) -> tuple[np.ndarray, float]:
        """(position, radius) without the cells behind the newest sighting along ``velocity`` that
        it did not see (module doc, the trail)."""
        if self.columns is None or self.inside is None or self.stale is None or not self.stale.any():
            return self.position, self.radius
        fresh = ~self.stale & (self.inside > 0)
        if not fresh.any():
            return self.position, self.radius
        xy, w = self.columns, self.inside
        ahead = (xy - (w[fresh] @ xy[fresh]) / w[fresh].sum()) @ velocity[:2] >= 0
        keep = (~self.stale | ahead) & (w > 0)
        centre = (w[keep] @ xy[keep]) / w[keep].sum()
        return np.array([centre[0], centre[1], self.position[2]]), _reach(xy[keep], centre, self.voxel_size)


def _reach(xy: np.ndarray, centre: np.ndarray, voxel_size: float) -> float:
    """A footprint's radius: its farthest cell centre (world x, y) from ``centre``, plus half a voxel."""
    return float(np.hypot(*(xy - centre[:2]).T).max()) + 0.5 * voxel_size


@jit
def _columns(grid: tuple, hits: tuple, lookup: tuple, band: tuple, numbers: tuple,
             flags: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One pass over the height band ``band`` = (k_lo, k_hi) of ``grid`` = (groups, labels, tsdf,
    weight): per (i, j) column, its movable voxels' fraction sum (0: none), fraction-weighted height
    sum, labelled-voxel count, a movable label and the newest ``hit`` of its voxels (the later of
    ``hits`` = (hit, hit2), hit2 the present layer's, when given). ``lookup`` = (group_ok,
    is_movable), ``numbers`` = (min_weight, voxel_size), ``flags`` = (use_tsdf, use_hit, use_hit2)."""
    groups, labels, tsdf, weight = grid
    hit, hit2 = hits
    group_ok, is_movable = lookup
    k_lo, k_hi = band
    min_weight, voxel_size = numbers
    use_tsdf, use_hit, use_hit2 = flags
    nx, ny = groups.shape[0], groups.shape[1]
    seen = np.full((nx, ny), NEVER, np.int32)
    frac = np.zeros((nx, ny), np.float64)
    fz = np.zeros((nx, ny), np.float64)
    seeds = np.zeros((nx, ny), np.int32)
    label = np.zeros((nx, ny), np.int32)
    body = np.zeros((nx, ny), np.bool_)
    for i in range(nx):
        for j in range(ny):
            for k in range(k_lo, k_hi):
                if not group_ok[groups[i, j, k]]:
                    continue
                lab = labels[i, j, k]
                if is_movable[lab]:
                    seeds[i, j] += 1
                    label[i, j] = lab
                elif lab != NO_LABEL:
                    continue
                elif use_tsdf and weight[i, j, k] < min_weight:
                    continue  # the never-observed fill is a guess at what hides behind, not the body
                body[i, j] = True
                if use_hit:
                    h = hit[i, j, k]
                    if use_hit2 and hit2[i, j, k] > h:
                        h = hit2[i, j, k]
                    if h > seen[i, j]:
                        seen[i, j] = h
                f = 1.0
                if use_tsdf and weight[i, j, k] >= min_weight:
                    # the voxel's inside fraction from its signed distance to the surface: a
                    # footprint's centre to well under a voxel, where binary cells jump by one
                    f = min(1.0, max(0.0, 0.5 - tsdf[i, j, k] / voxel_size))
                frac[i, j] += f
                fz[i, j] += f * k
    return body, frac, fz, seeds, label, seen


@dataclass(frozen=True)
class MapReading:
    """All the tracker reads of one map update (``Mapper.reading``), and nothing else of the map:
    the semantic occupancy and the layers it was made of (the present layer's overlay), the slice's
    height band, and the map's clocks. Without the TSDF layer (``tsdf``, ``weight``) voxels count
    whole; without ``hit`` no detection says when it was seen."""

    occupancy: np.ndarray  # per-voxel obstacle risk group
    band: tuple[int, int]  # z-voxel range [k_lo, k_hi) of the ESDF slice's height band
    origin: np.ndarray  # the volume's origin (m)
    voxel_size: float
    label: np.ndarray  # per-voxel label of the layers read
    label_to_group: np.ndarray
    tsdf: np.ndarray | None = None  # their signed distances and weights: a surface voxel is a sighting
    weight: np.ndarray | None = None
    min_weight: float = 0.5
    hit: np.ndarray | None = None  # when each voxel was last seen as a surface (the ``hit`` clock, ms)
    present_hit: np.ndarray | None = None  # the same for the current frame's layer, if there is one
    stamp_ns: int = 0  # the map's stamp
    now_ms: int | None = None  # the map's clock (``Mapper.now_ms``)


def detect(reading: MapReading, params: ObjectParams, dynamic: DynamicParams) -> list[Detection]:
    """The movable objects (``dynamic.dynamic_labels``) of one map reading: its semantic occupancy
    (the mapper's per-voxel risk group) with the semantic layer's labels, in its height band
    [k_lo, k_hi) of z voxels. With the TSDF layer, observed voxels count by their inside fraction;
    with its ``hit`` times (and the present layer's), each detection says when it was last seen."""
    r = reading
    groups, labels, origin, voxel_size, label_to_group = r.occupancy, r.label, r.origin, r.voxel_size, r.label_to_group
    tsdf, weight, hit, present_hit = r.tsdf, r.weight, r.hit, r.present_hit
    k_range = r.band
    movable = np.asarray(dynamic.dynamic_indices, dtype=np.int64)
    k_lo, k_hi = max(0, k_range[0]), min(groups.shape[2], k_range[1])
    if movable.size == 0 or k_hi <= k_lo:
        return []
    group_ok = np.zeros(256, dtype=np.bool_)
    group_ok[label_to_group[movable]] = True
    group_ok[0] = False  # a movable label the risk config makes free is never an obstacle
    if not group_ok.any():
        return []
    is_movable = np.zeros(65536, dtype=np.bool_)
    is_movable[movable] = True
    use_tsdf = tsdf is not None and weight is not None
    use_hit = use_tsdf and hit is not None
    dummy = np.zeros((1, 1, 1), np.float32)
    no_hit = np.zeros((1, 1, 1), np.int32)
    body, frac, fz, seeds, col_label, col_seen = _columns(
        (groups, labels, tsdf if use_tsdf else dummy, weight if use_tsdf else dummy),
        (hit if use_hit else no_hit, present_hit if use_hit and present_hit is not None else no_hit),
        (group_ok, is_movable), (k_lo, k_hi), (float(r.min_weight), float(voxel_size)),
        (use_tsdf, use_hit, use_hit and present_hit is not None))
    if not seeds.any():
        return []
    # Every cell grows by a disc of half the merge gap (whole voxels, rounded up) and touching
    # growths join: along the grid axes, parts up to 2 × grow voxels apart (a disc, not a square,
    # so diagonal parts do not join from farther).
    grow = math.ceil(params.object_merge_gap / voxel_size / 2 - 1e-9)
    disc = np.add.outer(np.arange(-grow, grow + 1) ** 2, np.arange(-grow, grow + 1) ** 2) <= grow * grow
    # Components over the box around the movable columns only (and the dilation's reach).
    bi, bj = np.nonzero(body.any(axis=1))[0], np.nonzero(body.any(axis=0))[0]
    i0, j0 = max(0, int(bi[0]) - grow - 1), max(0, int(bj[0]) - grow - 1)
    sub = body[i0:int(bi[-1]) + grow + 2, j0:int(bj[-1]) + grow + 2]
    joined = ndimage.binary_dilation(sub, disc) if grow > 0 else sub
    comp, n = ndimage.label(joined, structure=_EIGHT)
    ci, cj = np.nonzero(sub)
    cc = comp[ci, cj]
    ci += i0
    cj += j0
    w = frac[ci, cj]
    cells = np.bincount(cc, minlength=n + 1)
    fsum = np.bincount(cc, weights=w, minlength=n + 1)
    # A part is an object only if some voxel of it carries a movable label; the label with the most
    # such voxels names it (a person holding a dog's lead: the larger one).
    s = seeds[ci, cj]
    has = s > 0
    key = cc[has].astype(np.int64) * 65536 + col_label[ci[has], cj[has]]
    keys, first = np.unique(key, return_inverse=True)
    votes = np.bincount(first, weights=s[has])
    best: dict[int, tuple[int, float]] = {}
    for kk, c in zip(keys.tolist(), votes.tolist(), strict=True):
        cid, label = divmod(kk, 65536)
        if cid not in best or c > best[cid][1]:
            best[cid] = (label, c)
    min_cells = params.object_min_area / (voxel_size * voxel_size)
    ids = [cid for cid in best if cells[cid] >= min_cells - 1e-9 and fsum[cid] > 0]
    ids.sort(key=lambda cid: -fsum[cid])
    ids = ids[:params.object_max_count]
    if not ids:
        return []
    sx = np.bincount(cc, weights=w * ci, minlength=n + 1)
    sy = np.bincount(cc, weights=w * cj, minlength=n + 1)
    sz = np.bincount(cc, weights=fz[ci, cj], minlength=n + 1)
    order = np.argsort(cc, kind="stable")
    starts = np.searchsorted(cc[order], np.arange(n + 2))
    out = []
    for cid in ids:
        centre = origin + voxel_size * np.array([sx[cid], sy[cid], sz[cid]]) / fsum[cid]
        idx = order[starts[cid]:starts[cid + 1]]
        idx = idx[w[idx] > 0]
        xy = np.column_stack([origin[0] + ci[idx] * voxel_size, origin[1] + cj[idx] * voxel_size])
        det = Detection(best[cid][0], centre, _reach(xy, centre, voxel_size), int(cells[cid]))
        if use_hit and idx.size:
            seen = col_seen[ci[idx], cj[idx]]
            det.seen_ms = int(seen.max())
            det.columns = xy
            det.inside = w[idx]
            det.stale = seen < det.seen_ms - round(params.object_fresh_s * 1e3)
            det.voxel_size = voxel_size
        out.append(det)
    return out


@dataclass
class Track:
    id: int
    label: int
    position: np.ndarray
    radius: float
    first_ns: int
    last_ns: int
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    history: deque[tuple[int, float, float]] = field(default_factory=deque)  # (stamp, x, y)
    seen_ms: int | None = None  # the newest sighting of its footprint (``Detection.seen_ms``)


class ObjectTracker:
    """Footprints of movable objects → tracks with velocities, across map updates (module doc)."""

    def __init__(self, params: ObjectParams | None = None, dynamic: DynamicParams | None = None):
        """``params``: the tracker's own; ``dynamic``: which labels move and how long they are kept."""
        self.params = params or ObjectParams()
        self.dynamic = dynamic or DynamicParams()
        self.tracks: list[Track] = []
        self.stamp_ns = 0
        self.now_ms: int | None = None  # the map's clock at the last update (``Mapper.now_ms``)
        # Where people and animals were last seen standing: id → (position, radius, seen_ms), kept
        # for ``dynamic_persist_s`` whether or not the track lives on (``protected``).
        self.standing: dict[int, tuple[np.ndarray, float, int | None]] = {}
        self._next_id = 0

    @classmethod
    def of(cls, config: MapperConfig) -> ObjectTracker:
        """Wired from a whole mapper configuration: its ``ObjectParams`` and ``DynamicParams``."""
        return cls(config.objects, config.dynamic)

    @classmethod
    def warmed(cls, params: ObjectParams | None = None, dynamic: DynamicParams | None = None) -> ObjectTracker:
        """A tracker whose kernel is compiled (or loaded from numba's cache): for a node, before serving."""
        g = np.ones((3, 3, 1), np.uint8)
        lab = np.full((3, 3, 1), NO_LABEL, np.uint16)
        lab[1, 1, 0] = 12
        f = np.zeros((3, 3, 1), np.float32)
        lut = np.ones(65536, np.uint8)
        bare = MapReading(g, (0, 1), np.zeros(3), 0.05, lab, lut)
        person = DynamicParams(dynamic_labels=("person",))
        detect(replace(bare, tsdf=f, weight=f), ObjectParams(), person)
        detect(bare, ObjectParams(), person)
        return cls(params, dynamic)

    def reset(self) -> None:
        """Forget every track (ids keep counting up: never reused by one publisher)."""
        self.tracks.clear()
        self.standing.clear()
        self.stamp_ns = 0
        self.now_ms = None

    def update_map(self, reading: MapReading | None, stamp_ns: int | None = None) -> list[TrackedObject]:
        """One map update, as ``Mapper.reading`` gives it (None: no map yet): the movable objects of
        its height band, tracked, at the map's stamp (or ``stamp_ns``)."""
        if reading is None:
            return []
        stamp = reading.stamp_ns if stamp_ns is None else stamp_ns
        return self.update(stamp, detect(reading, self.params, self.dynamic), reading.label_to_group, reading.now_ms)

    def update(self, stamp_ns: int, detections: list[Detection], label_to_group: np.ndarray | None = None,
               now_ms: int | None = None) -> list[TrackedObject]:
        """Associate one update's detections (made from data of ``stamp_ns``; ``now_ms`` on the map's
        ``hit`` clock) with the tracks, update their velocities, expire old tracks; the objects to
        publish. A footprint no frame has seen since the last update (``Detection.seen_ms``: out
        of view, occluded) is no sighting: it neither moves its track nor starts one."""
        p = self.params
        if stamp_ns < self.stamp_ns:  # time went back (a replay, a restarted sender): start over
            self.reset()
        if stamp_ns == self.stamp_ns and self.tracks:  # no newer data: nothing observed anew
            return self.objects(label_to_group)
        self.stamp_ns = stamp_ns
        since = self.now_ms
        self.now_ms = now_ms
        pairs = []
        for ti, tr in enumerate(self.tracks):
            dt = (stamp_ns - tr.last_ns) * 1e-9
            predicted = tr.position[:2] + tr.velocity[:2] * dt
            gate = p.object_gate + p.object_max_speed * dt
            for di, d in enumerate(detections):
                if d.label != tr.label or np.hypot(*(d.position[:2] - tr.position[:2])) > gate:
                    continue
                pairs.append((float(np.hypot(*(d.position[:2] - predicted))), ti, di))
        pairs.sort()
        used_t: set[int] = set()
        used_d: set[int] = set()
        for _, ti, di in pairs:
            if ti in used_t or di in used_d:
                continue
            used_t.add(ti)
            used_d.add(di)
            tr, d = self.tracks[ti], detections[di]
            if d.seen_ms is None or tr.seen_ms is None or d.seen_ms > tr.seen_ms:
                self._observe(tr, d, stamp_ns)
        for di, d in enumerate(detections):
            if di not in used_d and (d.seen_ms is None or since is None or d.seen_ms > since):
                tr = Track(self._next_id, d.label, d.position.copy(), d.radius, stamp_ns, stamp_ns, seen_ms=d.seen_ms)
                tr.history.append((stamp_ns, float(d.position[0]), float(d.position[1])))
                self._next_id += 1
                self.tracks.append(tr)
        for tr in self.tracks:
            if tr.last_ns == stamp_ns:  # seen in this update
                if tr.velocity.any():
                    self.standing.pop(tr.id, None)
                else:
                    self.standing[tr.id] = (tr.position.copy(), tr.radius, tr.seen_ms)
        if now_ms is not None:
            oldest = now_ms - round(self.dynamic.dynamic_persist_s * 1e3)
            self.standing = {k: v for k, v in self.standing.items() if v[2] is None or v[2] >= oldest}
        expire_ns = p.object_expire_s * 1e9
        self.tracks = [t for t in self.tracks if stamp_ns - t.last_ns <= expire_ns]
        return self.objects(label_to_group)

    def _observe(self, tr: Track, d: Detection, stamp_ns: int) -> None:
        p = self.params
        position, tr.radius = d.without_trail(tr.velocity) if tr.velocity.any() else (d.position, d.radius)
        tr.position, tr.last_ns = position.copy(), stamp_ns
        tr.seen_ms = d.seen_ms
        h = tr.history
        h.append((stamp_ns, float(position[0]), float(position[1])))
        while h and stamp_ns - h[0][0] > p.object_window_s * 1e9:
            h.popleft()
        tr.velocity = np.zeros(3)
        if len(h) < p.object_min_samples:
            return
        arr = np.asarray(h, dtype=np.float64)
        t = (arr[:, 0] - arr[-1, 0]) * 1e-9
        t -= t.mean()
        den = float((t * t).sum())
        if den <= 0.0:
            return
        v = (t[:, None] * (arr[:, 1:] - arr[:, 1:].mean(axis=0))).sum(axis=0) / den
        speed = float(np.hypot(v[0], v[1]))
        if not math.isfinite(speed) or speed < p.object_deadband:
            return
        if speed > p.object_max_speed:
            v *= p.object_max_speed / speed
        tr.velocity = np.array([v[0], v[1], 0.0])

    def protected(self) -> list[tuple[np.ndarray, float]]:
        """Footprints (position, radius ≤ ``object_body_radius``) the map must keep people and animals in for
        ``dynamic_persist_s`` (``DynamicDecay`` forgets their voxels elsewhere after
        ``dynamic_moving_persist_s``): where each was last seen standing (a track too new for a
        velocity counts as standing), and where each track seen within ``dynamic_moving_persist_s``
        is. A walker who left the view, and the place a person stood before walking off, are not."""
        body = self.params.object_body_radius
        out = {k: (pos.copy(), min(radius, body)) for k, (pos, radius, _) in self.standing.items()}
        if self.now_ms is not None:
            oldest = self.now_ms - round(self.dynamic.dynamic_moving_persist_s * 1e3)
            for tr in self.tracks:
                if tr.seen_ms is None or tr.seen_ms >= oldest:
                    out[tr.id] = (tr.position.copy(), min(tr.radius, body))
        return list(out.values())

    def objects(self, label_to_group: np.ndarray | None = None) -> list[TrackedObject]:
        """The tracks as messages, at the tracker's stamp; ``label_to_group`` gives their risk group."""
        out = []
        for tr in self.tracks:
            if not (np.isfinite(tr.position).all() and np.isfinite(tr.velocity).all() and math.isfinite(tr.radius)):
                continue  # never published non-finite (coordinates come from a finite grid: defensive)
            group = int(label_to_group[tr.label]) if label_to_group is not None else 0
            out.append(TrackedObject(
                id=tr.id, label=tr.label, risk_group=group, position=tuple(tr.position.tolist()),
                velocity=tuple(tr.velocity.tolist()), radius=tr.radius,
                age_ms=(self.stamp_ns - tr.last_ns) / 1e6, tracked_ms=(tr.last_ns - tr.first_ns) / 1e6))
        return out


__all__ = ["Detection", "MapReading", "ObjectTracker", "Track", "detect"]
