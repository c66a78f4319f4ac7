"""Procedural semantic indoor scenes from a seed: a closed room (floor, ceiling, four walls) with
furniture against the walls and boxes, balls, people and animals in the open floor, and walkers:
people going back and forth between two free spots.

Deterministic: the same seed and counts give the same objects, on every machine (numpy's
``default_rng`` (PCG64) stream). Placement is rejection sampling of footprint circles with a
clearance between objects and a clear disc around the robot's start, so no two objects overlap
(which keeps the ground-truth signed distance well defined, see ``scene``). A walker's whole path
keeps that clearance from the fixed objects and the robot's start; walkers may cross each other.
Walkers are drawn after everything else, so adding them leaves a seed's other objects as they were.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import ade20k

from ..geometry.transforms import pose_matrix
from . import shapes
from .scene import LIFT, Motion, SceneObject

#: Default object dimensions (m) per class: (size_x, size_y, size_z) of the footprint box / body.
DEFAULT_SIZES: dict[str, tuple[float, float, float]] = {
    "table": (1.2, 0.7, 0.75),
    "chair": (0.45, 0.45, 0.9),
    "sofa": (1.8, 0.8, 0.8),
    "cabinet": (0.8, 0.4, 1.2),
    "bed": (2.0, 1.4, 0.5),
    "box": (0.4, 0.4, 0.4),
    "ball": (0.24, 0.24, 0.24),
    "person": (0.44, 0.44, 1.7),
    "animal": (0.7, 0.3, 0.5),
}
FURNITURE = ("table", "chair", "sofa", "cabinet", "bed")


def object_mesh(class_name: str, size: tuple[float, float, float] | None = None, shape: str = "auto") -> shapes.Mesh:
    """The mesh of an object of an ADE20K class: a capsule for a person, an ellipsoid for an
    animal, a sphere for a ball, a box for everything else (``shape`` overrides)."""
    sx, sy, sz = size if size is not None else DEFAULT_SIZES.get(class_name, (0.5, 0.5, 0.5))
    if min(sx, sy, sz) <= 0:
        raise ValueError(f"{class_name}: sizes must be positive, got {(sx, sy, sz)}")
    if shape == "auto":
        shape = {"person": "capsule", "animal": "ellipsoid", "ball": "sphere"}.get(class_name, "box")
    if shape == "box":
        return shapes.box(sx, sy, sz)
    if shape == "ellipsoid":
        return shapes.ellipsoid(sx / 2, sy / 2, sz / 2)
    if shape == "sphere":
        return shapes.sphere(max(sx, sy, sz) / 2)
    if shape == "cylinder":
        return shapes.cylinder(max(sx, sy) / 2, sz)
    if shape == "capsule":
        r = max(sx, sy) / 2
        return shapes.capsule(r, max(sz, 2 * r))
    raise ValueError(f"unknown shape {shape!r}: use auto, box, ellipsoid, sphere, cylinder or capsule")


def room(size_x: float, size_y: float, height: float = 2.5, thickness: float = 0.1, ceiling: bool = True,
         ) -> list[SceneObject]:
    """A closed room centred on the origin, inner floor at z = 0: floor and ceiling slabs and
    four wall slabs that touch but never overlap (disjoint closed meshes)."""
    if min(size_x, size_y, height, thickness) <= 0:
        raise ValueError("room sizes must be positive")
    hx, hy, t = size_x / 2, size_y / 2, thickness
    wall, floor, ceil = ade20k.index("wall"), ade20k.index("floor"), ade20k.index("ceiling")
    parts = [
        ("floor", floor, (-hx - t, -hy - t, -t), (hx + t, hy + t, 0.0)),
        ("wall_west", wall, (-hx - t, -hy - t, 0.0), (-hx, hy + t, height)),
        ("wall_east", wall, (hx, -hy - t, 0.0), (hx + t, hy + t, height)),
        ("wall_south", wall, (-hx, -hy - t, 0.0), (hx, -hy, height)),
        ("wall_north", wall, (-hx, hy, 0.0), (hx, hy + t, height)),
    ]
    if ceiling:
        parts.append(("ceiling", ceil, (-hx - t, -hy - t, height), (hx + t, hy + t, height + t)))
    return [SceneObject(name, label, shapes.slab(lo, hi)) for name, label, lo, hi in parts]


@dataclass(frozen=True)
class Placement:
    """One object to place: class, floor pose and size (what a scenario file would list)."""

    class_name: str
    x: float
    y: float
    yaw: float
    size: tuple[float, float, float]
    waypoints: tuple[tuple[float, float], ...] | None = None  # a walker's path (pingpong), from (x, y)
    speed: float = 0.0


def _radius(size: tuple[float, float, float]) -> float:
    return 0.5 * math.hypot(size[0], size[1])


@dataclass(frozen=True)
class Furnishing:
    """What a procedural room holds: pieces of furniture (against the walls), boxes, balls, standing
    people and animals, and walkers going back and forth at a speed drawn from ``walker_speed`` (m/s)."""

    furniture: int = 4
    boxes: int = 2
    balls: int = 1
    people: int = 1
    animals: int = 1
    walkers: int = 0
    walker_speed: tuple[float, float] = (0.5, 1.5)


def random_placements(seed: int, size_x: float, size_y: float, furnishing: Furnishing = Furnishing(), *,
                      keep_clear: tuple[float, float, float] = (0.0, 0.0, 0.8), clearance: float = 0.25,
                      max_tries: int = 400) -> list[Placement]:
    """Deterministic placements of ``furnishing`` for a room ``size_x × size_y`` centred on the origin.

    Furniture goes against a random wall (its back to the wall), the rest anywhere on the open
    floor; nothing within ``keep_clear = (x, y, radius)``. Objects that find no free spot after
    ``max_tries`` are skipped (a crowded room gets fewer objects, never overlapping ones). A walker
    goes back and forth between two free spots at least 1.5 m apart."""
    f = furnishing
    rng = np.random.default_rng(seed)
    placed: list[tuple[float, float, float]] = [keep_clear]
    out: list[Placement] = []
    hx, hy = size_x / 2, size_y / 2

    def free(x: float, y: float, r: float) -> bool:
        return all(math.hypot(x - px, y - py) >= r + pr + clearance for px, py, pr in placed)

    wanted = ([str(rng.choice(FURNITURE)) for _ in range(f.furniture)] + ["box"] * f.boxes + ["ball"] * f.balls
              + ["person"] * f.people + ["animal"] * f.animals)
    for name in wanted:
        base = DEFAULT_SIZES[name]
        jitter = rng.uniform(0.85, 1.15, size=3)
        size = (base[0] * jitter[0], base[1] * jitter[1], base[2] * jitter[2])
        if name in ("ball", "person"):
            size = (size[0], size[0], size[2])  # round things stay round
        r = _radius(size)
        for _ in range(max_tries):
            if name in FURNITURE:
                side = int(rng.integers(4))
                along = rng.uniform(-1.0, 1.0)
                depth = size[1] / 2 + 0.02
                # Long side (local x) along the wall, depth (local y) away from it.
                if side < 2:  # south / north wall
                    x, yaw = along * max(0.0, hx - size[0] / 2 - 0.05), 0.0
                    y = (-hy + depth) if side == 0 else (hy - depth)
                else:  # east / west wall
                    y, yaw = along * max(0.0, hy - size[0] / 2 - 0.05), math.pi / 2
                    x = (hx - depth) if side == 2 else (-hx + depth)
            else:
                x = rng.uniform(-hx + r + 0.05, hx - r - 0.05) if hx > r + 0.05 else 0.0
                y = rng.uniform(-hy + r + 0.05, hy - r - 0.05) if hy > r + 0.05 else 0.0
                yaw = rng.uniform(-math.pi, math.pi)
            # Enclosing circles: conservative, so footprints can never overlap.
            if free(x, y, r):
                placed.append((x, y, r))
                out.append(Placement(name, float(x), float(y), float(yaw), size))
                break
    for _ in range(f.walkers):
        base = DEFAULT_SIZES["person"]
        jitter = rng.uniform(0.85, 1.15, size=2)
        size = (base[0] * jitter[0], base[0] * jitter[0], base[2] * jitter[1])
        r = size[0] / 2  # a walker's footprint: its capsule's circle
        speed = float(rng.uniform(*f.walker_speed))
        for _ in range(max_tries):
            a = [rng.uniform(-hx + r + 0.05, hx - r - 0.05), rng.uniform(-hy + r + 0.05, hy - r - 0.05)]
            b = [rng.uniform(-hx + r + 0.05, hx - r - 0.05), rng.uniform(-hy + r + 0.05, hy - r - 0.05)]
            length = math.hypot(b[0] - a[0], b[1] - a[1])
            if length < 1.5:
                continue
            steps = np.linspace(0.0, 1.0, max(2, int(length / 0.05) + 1))
            if all(free(a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), r) for s in steps):
                yaw = math.atan2(b[1] - a[1], b[0] - a[0])
                out.append(Placement("person", float(a[0]), float(a[1]), yaw, size,
                                     ((float(a[0]), float(a[1])), (float(b[0]), float(b[1]))), speed))
                break
    return out


def build_objects(placements: list[Placement], prefix: str = "") -> list[SceneObject]:
    """Scene objects of placements, named ``<prefix><class>_<n>``."""
    counts: dict[str, int] = {}
    objs = []
    for p in placements:
        n = counts[p.class_name] = counts.get(p.class_name, 0) + 1
        motion = None if p.waypoints is None else Motion(np.asarray(p.waypoints), p.speed, "pingpong")
        objs.append(SceneObject(f"{prefix}{p.class_name}_{n}", ade20k.index(p.class_name),
                                object_mesh(p.class_name, p.size), pose_matrix(p.x, p.y, LIFT, p.yaw),
                                motion=motion))
    return objs


def random_room(seed: int, size: tuple[float, float] | None = None, height: float = 2.5, **counts: int
                ) -> list[SceneObject]:
    """A whole procedural room: size drawn from the seed (4–8 m × 4–7 m) unless given."""
    rng = np.random.default_rng([seed, 7])
    sx, sy = size if size is not None else (float(rng.uniform(4.0, 8.0)), float(rng.uniform(4.0, 7.0)))
    return room(sx, sy, height) + build_objects(random_placements(seed, sx, sy, Furnishing(**counts)))
