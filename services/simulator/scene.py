"""A semantic scene: labelled objects (a mesh, an ADE20K label, a name, optional motion and
appearance time) turned, for any instant, into one open3d ``RaycastingScene``.

Ground truth from it:

* ``signed_distance(points)`` — open3d ``compute_signed_distance``: the distance to the
  nearest surface, negative inside a closed surface. The sign comes from counting ray
  crossings, so it is only right for **watertight, non-intersecting** meshes: primitives from
  ``shapes`` are closed, walls and floor are disjoint slabs, and objects are lifted ``LIFT``
  above the floor so no two meshes share a face. Loaded scans (``mesh_io``) are usually open:
  use ``distance`` (unsigned) for them.
* ``cast_packed(rays)`` — open3d's first hit per ray; the renderer (``camera.Renderer``) reads
  the ADE20K label (per object, or per triangle for loaded meshes) and the index of the object
  hit from the snapshot's tables (``offsets``, ``triangle_labels``, ``object_index``).

The raycasting structure is rebuilt only when the set of present objects or the pose of a
moving one changes; static scenes are built once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from riskfield.protocol import ade20k

from .shapes import Mesh, transform

#: Gap (m) between objects and the floor, so that their meshes never share a face.
LIFT = 1e-3
#: Label of pixels/rays that hit nothing (ADE20K has no "void"; 65535 is out of its range).
NO_LABEL = np.uint16(65535)


@dataclass
class Motion:
    """How an object moves once it is present: along ``waypoints`` (K×2 floor positions) at
    ``speed`` m/s — back and forth (``pingpong``), around (``loop``) or once then still
    (``once``) — or, without waypoints, at a constant floor ``velocity`` (m/s) from its
    start position. ``waits`` (K seconds, optional) is how long it stands at each waypoint
    before leaving it, on every visit: a first wait delays the start, a middle one makes a
    walker stop, and a path that comes back (``[a, b, a]``) a walker that stops and turns.
    A moving object faces its direction of travel; a standing one keeps the heading it came
    with (at the start: the heading of its first leg)."""

    waypoints: np.ndarray | None = None
    speed: float = 0.5
    mode: str = "pingpong"
    velocity: tuple[float, float] = (0.0, 0.0)
    waits: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.mode not in ("pingpong", "loop", "once"):
            raise ValueError(f"motion mode {self.mode!r}: use pingpong, loop or once")
        if not np.isfinite(self.speed) or self.speed < 0:
            raise ValueError("speed must be finite and non-negative")
        if self.waypoints is None:
            if self.waits is not None:
                raise ValueError("waits need waypoints")
            return
        self.waypoints = np.asarray(self.waypoints, np.float64).reshape(-1, 2)
        k = len(self.waypoints)
        if k < 2:
            raise ValueError("a path needs at least two waypoints")
        waits = np.zeros(k) if self.waits is None else np.asarray(self.waits, np.float64).reshape(-1)
        if len(waits) != k or not np.isfinite(waits).all() or (waits < 0).any():
            raise ValueError("waits need one finite, non-negative duration per waypoint")
        self.waits = waits
        # One period as a timeline of phases: stand at a waypoint, then walk to the next visit.
        visits = {"once": list(range(k)), "loop": [*range(k), 0],
                  "pingpong": [*range(k), *range(k - 2, -1, -1)]}[self.mode]
        p = self.waypoints[visits]
        legs = np.diff(p, axis=0)
        lengths = np.linalg.norm(legs, axis=1)
        walk = lengths / self.speed if self.speed > 0 else np.where(lengths > 0, np.inf, 0.0)
        stand = waits[visits[:-1]]
        self._from, self._legs, self._lengths = p[:-1], legs, lengths
        # phase j: stand on [starts[2j], starts[2j+1]), walk on [starts[2j+1], starts[2j+2])
        durations = np.column_stack([stand, walk]).reshape(-1)
        self._starts = np.concatenate([[0.0], np.cumsum(durations)])
        self._still = self.speed == 0 or not np.isfinite(self._starts[-1]) or self._starts[-1] == 0

    def state(self, start_xy: np.ndarray, start_yaw: float, elapsed_s: float
              ) -> tuple[np.ndarray, float, np.ndarray]:
        """Floor position, yaw and floor velocity (m/s) ``elapsed_s`` after the motion started."""
        elapsed_s = max(0.0, elapsed_s)
        if self.waypoints is None:
            v = np.asarray(self.velocity, np.float64)
            yaw = float(np.arctan2(v[1], v[0])) if np.any(v) else start_yaw
            return start_xy + v * elapsed_s, yaw, v.copy()
        if self._still:
            return self.waypoints[0].copy(), start_yaw, np.zeros(2)
        period = float(self._starts[-1])
        s = elapsed_s
        if self.mode == "once":
            if s >= period:
                return self._from[-1] + self._legs[-1], self._heading(len(self._legs), start_yaw), np.zeros(2)
        else:
            s = s % period
        phase = min(int(np.searchsorted(self._starts, s, side="right")) - 1, len(self._starts) - 2)
        j, walking = divmod(phase, 2)
        if not walking:
            return self._from[j].copy(), self._heading(j, start_yaw), np.zeros(2)
        if self._lengths[j] == 0:
            return self._from[j].copy(), self._heading(j, start_yaw), np.zeros(2)
        d = self._legs[j] / self._lengths[j]
        pos = self._from[j] + d * self.speed * (s - float(self._starts[phase]))
        return pos, float(np.arctan2(d[1], d[0])), d * self.speed

    def _heading(self, j: int, start_yaw: float) -> float:
        """Heading when standing at visit ``j``: of the leg that arrived there (the first leg's at the
        start), the nearest non-empty one; ``start_yaw`` if every leg is empty."""
        order = range(j - 1, -1, -1) if j > 0 else range(len(self._legs))
        for i in order:
            if self._lengths[i] > 0:
                return float(np.arctan2(self._legs[i][1], self._legs[i][0]))
        return start_yaw

    def place(self, start_xy: np.ndarray, start_yaw: float, elapsed_s: float) -> tuple[np.ndarray, float]:
        """Floor position and yaw ``elapsed_s`` after the motion started."""
        pos, yaw, _ = self.state(start_xy, start_yaw, elapsed_s)
        return pos, yaw


@dataclass
class SceneObject:
    """One labelled object. ``mesh`` is in the object's local frame (see ``shapes``); ``pose``
    is its 4x4 placement at the start. ``triangle_labels`` (per triangle) overrides ``label``
    for loaded, multi-class meshes. ``appear_at_s``: absent before that time (the paper's
    unseen obstacle); ``motion``: moves after appearing."""

    name: str
    label: int
    mesh: Mesh
    pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    triangle_labels: np.ndarray | None = None
    motion: Motion | None = None
    appear_at_s: float = 0.0
    watertight: bool = True

    def __post_init__(self) -> None:
        if not 0 <= int(self.label) < ade20k.NUM_CLASSES:
            raise ValueError(f"{self.name}: label {self.label} is not an ADE20K class index")
        v, t = self.mesh
        if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
            raise ValueError(f"{self.name}: mesh must be Nx3 vertices and Mx3 (M ≥ 1) triangles")
        if t.max() >= len(v):
            raise ValueError(f"{self.name}: a triangle indexes a vertex that does not exist")
        if not np.isfinite(v).all():
            raise ValueError(f"{self.name}: non-finite vertex")
        if self.triangle_labels is not None and len(self.triangle_labels) != len(t):
            raise ValueError(f"{self.name}: one triangle label per triangle is required")
        self.pose = np.asarray(self.pose, np.float64)

    @property
    def class_name(self) -> str:
        return ade20k.CLASSES[self.label]

    @property
    def moving(self) -> bool:
        return self.motion is not None

    def present(self, t: float) -> bool:
        return t >= self.appear_at_s

    def pose_at(self, t: float) -> np.ndarray:
        return self.state_at(t)[0]

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The 4x4 pose and the floor velocity (m/s, x and y) at time ``t``."""
        if self.motion is None:
            return self.pose, np.zeros(2)
        yaw0 = float(np.arctan2(self.pose[1, 0], self.pose[0, 0]))
        xy, yaw, v = self.motion.state(self.pose[:2, 3], yaw0, t - self.appear_at_s)
        c, s = np.cos(yaw), np.sin(yaw)
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:2, 3] = xy
        T[2, 3] = self.pose[2, 3]
        return T, v if self.present(t) else np.zeros(2)

    @property
    def footprint_radius(self) -> float:
        """Horizontal radius (m) of the upright cylinder about the object's origin that holds its mesh."""
        v = self.mesh[0]
        return float(np.hypot(v[:, 0], v[:, 1]).max())

    @property
    def height(self) -> float:
        """Top of the mesh above the object's origin (m)."""
        return float(self.mesh[0][:, 2].max())

    def world_mesh(self, t: float = 0.0) -> Mesh:
        return transform(self.mesh, self.pose_at(t))


class Snapshot:
    """The scene frozen at one instant, ready for ray casting and distance queries."""

    def __init__(self, objects: Sequence[SceneObject], t: float):
        self.t = t
        self.raycaster = o3d.t.geometry.RaycastingScene()
        self.watertight = True
        obj_index, offsets, tri_labels = [], [], []
        n = 0
        for i, obj in enumerate(objects):
            if not obj.present(t):
                continue
            v, tri = obj.world_mesh(t)
            self.raycaster.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(tri))
            obj_index.append(i)
            offsets.append(n)
            labels = obj.triangle_labels if obj.triangle_labels is not None else np.full(len(tri), obj.label)
            tri_labels.append(np.asarray(labels, np.uint16))
            n += len(tri)
            self.watertight &= obj.watertight
        self.object_index = np.asarray([*obj_index, -1], np.int32)  # last entry: "no hit"
        self.offsets = np.asarray([*offsets, 0], np.int64)
        self.triangle_labels = np.concatenate([*tri_labels, np.array([NO_LABEL], np.uint16)])
        self.n_triangles = n
        self.empty = not obj_index

    def cast_packed(self, rays: np.ndarray) -> dict[str, np.ndarray]:
        """open3d's ``cast_rays`` output (``t_hit``, ``geometry_ids``, ``primitive_ids``,
        ``primitive_normals``, …) as flat numpy arrays, one entry per ray, for rays packed as open3d
        wants them: (N, 6) float32 rows of origin and direction, C-contiguous (open3d wraps the
        buffer without a copy); a non-empty scene only."""
        out = self.raycaster.cast_rays(o3d.core.Tensor.from_numpy(rays))
        return {k: v.numpy() for k, v in out.items()}

    def _points(self, points: np.ndarray) -> tuple[o3d.core.Tensor, tuple[int, ...]]:
        p = np.asarray(points, np.float32)
        if p.shape[-1] != 3:
            raise ValueError(f"points must have shape (..., 3), got {p.shape}")
        return o3d.core.Tensor(np.ascontiguousarray(p.reshape(-1, 3))), p.shape[:-1]

    def signed_distance(self, points: np.ndarray, nsamples: int = 3) -> np.ndarray:
        """Signed distance (m) to the nearest surface, < 0 inside an object (see module doc).

        ``nsamples`` rays (odd) vote on inside/outside, which keeps the sign right for query
        points whose first ray grazes an edge."""
        if self.empty:
            return np.full(np.shape(points)[:-1], np.inf, np.float32)
        q, shape = self._points(points)
        return self.raycaster.compute_signed_distance(q, nsamples=nsamples).numpy().reshape(shape)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance (m) to the nearest surface (valid for open meshes too)."""
        if self.empty:
            return np.full(np.shape(points)[:-1], np.inf, np.float32)
        q, shape = self._points(points)
        return self.raycaster.compute_distance(q).numpy().reshape(shape)

    def nearest_label(self, points: np.ndarray) -> np.ndarray:
        """ADE20K label of the surface nearest to each point (``NO_LABEL`` in an empty scene)."""
        q, shape = self._points(points)
        if self.empty:
            return np.full(shape, NO_LABEL, np.uint16)
        out = self.raycaster.compute_closest_points(q)
        gid = out["geometry_ids"].numpy().astype(np.int64)
        pid = out["primitive_ids"].numpy().astype(np.int64)
        return self.triangle_labels[self.offsets[gid] + pid].reshape(shape)


class Scene:
    """Labelled objects plus a cached snapshot per instant (rebuilt only when needed)."""

    def __init__(self, objects: Sequence[SceneObject] = ()):
        self.objects: list[SceneObject] = []
        self._snapshot: Snapshot | None = None
        self._snapshot_key: tuple | None = None
        self.rebuilds = 0
        for obj in objects:
            self.add(obj)

    def add(self, obj: SceneObject) -> int:
        """Add an object (also while running: the next snapshot includes it); its index."""
        if any(o.name == obj.name for o in self.objects):
            raise ValueError(f"an object named {obj.name!r} is already in the scene")
        self.objects.append(obj)
        self._snapshot_key = None
        return len(self.objects) - 1

    def remove(self, name: str) -> None:
        self.objects = [o for o in self.objects if o.name != name]
        self._snapshot_key = None

    def __getitem__(self, name: str) -> SceneObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(name)

    @property
    def dynamic(self) -> bool:
        return any(o.moving or o.appear_at_s > 0 for o in self.objects)

    def _key(self, t: float) -> tuple:
        # What decides the geometry at time t: which objects are present, where moving ones are.
        return (len(self.objects), tuple(o.present(t) for o in self.objects),
                tuple(round(t, 6) if o.moving and o.present(t) else None for o in self.objects))

    def at(self, t: float = 0.0) -> Snapshot:
        """The snapshot at time ``t`` (cached while nothing changes)."""
        key = self._key(t)
        if self._snapshot is None or key != self._snapshot_key:
            self._snapshot = Snapshot(self.objects, t)
            self._snapshot_key = key
            self.rebuilds += 1
        return self._snapshot

    def signed_distance(self, points: np.ndarray, t: float = 0.0) -> np.ndarray:
        return self.at(t).signed_distance(points)

    def bounds(self, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds of everything present at ``t``."""
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for o in self.objects:
            if o.present(t):
                v = o.world_mesh(t)[0]
                lo, hi = np.minimum(lo, v.min(0)), np.maximum(hi, v.max(0))
        return lo, hi
