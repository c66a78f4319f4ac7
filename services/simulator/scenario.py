"""Scenario files: the room, the objects (fixed, moving, appearing later), the robot and the camera.

A scenario is YAML (or the same structure as a dict; built-in ones are listed in ``BUILTIN``)::

    name: teleop_dog
    room: {size: [8.0, 4.0], height: 2.5}        # closed room centred on the origin
    procedural: {seed: 3, furniture: 4, boxes: 2, balls: 1, people: 0, animals: 0, walkers: 2}   # optional
    objects:
      - class: animal                              # ADE20K name (or index)
        position: [1.0, 0.0]                       # floor x, y (m)
        yaw: 3.14
        size: [0.7, 0.3, 0.5]                      # optional; per-class default otherwise
      - class: person
        position: [0.0, -1.5]
        waypoints: [[0.0, -1.5], [0.0, 1.5]]       # walks back and forth ...
        speed: 0.6                                 # ... at 0.6 m/s
      - class: person
        position: [2.0, -2.0]
        waypoints: [[2.0, -2.0], [2.0, 0.0], [2.0, -2.0]]
        waits: [1.0, 3.0, 0.0]                     # starts after 1 s, stops 3 s, turns back
        motion: once
      - class: box
        position: [2.0, 0.0]
        appear_at_s: 12.0                          # the unseen obstacle
      - mesh: scans/room.ply                       # a labelled PLY (relative to the file)
    robot: {type: limo, start: [-3.0, 0.0, 0.0]}   # x, y, yaw; limo|ackermann|mecanum|…
    camera: {width: 512, height: 384, hfov_deg: 90, mount: {x: 0.15, z: 0.1, pitch_deg: 0}}
    goals: [[2.0, 2.0], [2.0, -2.0]]               # optional, for the navigator

``load_scenario(name_or_path)`` validates it; ``build_scene(scenario)`` makes the ``Scene``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from riskfield.protocol import ade20k
from riskfield.protocol.platforms import LIMO, CameraMount

from ..geometry.camera import PinholeCamera
from ..geometry.transforms import pose_matrix
from . import procedural
from .mesh_io import load_labelled_ply
from .robots import resolve_robot_type
from .scene import LIFT, Motion, Scene, SceneObject

Finite = Field(allow_inf_nan=False)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class RoomSpec(_Model):
    size: tuple[float, float] = (6.0, 6.0)
    height: float = Field(2.5, gt=0, le=20)
    wall_thickness: float = Field(0.1, gt=0, le=2)
    ceiling: bool = True

    @field_validator("size")
    @classmethod
    def _positive(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not all(0 < s <= 200 and math.isfinite(s) for s in v):
            raise ValueError("room size must be positive and at most 200 m")
        return v


class ProceduralSpec(_Model):
    seed: int = 0
    furniture: int = Field(4, ge=0, le=100)
    boxes: int = Field(2, ge=0, le=100)
    balls: int = Field(1, ge=0, le=100)
    people: int = Field(1, ge=0, le=100)
    animals: int = Field(1, ge=0, le=100)
    walkers: int = Field(0, ge=0, le=100, description="people walking back and forth between two free spots")
    walker_speed: tuple[float, float] = Field((0.5, 1.5), description="range their speeds are drawn from (m/s)")

    @field_validator("walker_speed")
    @classmethod
    def _speed_range(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (math.isfinite(v[0]) and math.isfinite(v[1]) and 0 <= v[0] <= v[1] <= 20):
            raise ValueError("walker_speed must be (low, high) with 0 ≤ low ≤ high ≤ 20 m/s")
        return v


class ObjectSpec(_Model):
    """One object: a primitive of an ADE20K class, or a labelled mesh file."""

    class_: str | int | None = Field(None, alias="class")
    mesh: str | None = None
    name: str | None = None
    position: tuple[float, float] = (0.0, 0.0)
    z: float = 0.0
    yaw: float = 0.0
    size: tuple[float, float, float] | None = None
    shape: Literal["auto", "box", "ellipsoid", "sphere", "cylinder", "capsule"] = "auto"
    waypoints: list[tuple[float, float]] | None = None
    speed: float = Field(0.5, ge=0, le=20)
    waits: list[float] | None = None  # seconds standing at each waypoint, one per waypoint (``scene.Motion``)
    velocity: tuple[float, float] | None = None
    motion: Literal["pingpong", "loop", "once"] = "pingpong"
    appear_at_s: float = Field(0.0, ge=0)
    names: list[str] | None = None  # for meshes: dataset label id → class name

    @model_validator(mode="after")
    def _one_kind(self) -> ObjectSpec:
        if (self.class_ is None) == (self.mesh is None):
            raise ValueError("an object needs exactly one of 'class' or 'mesh'")
        nums = [*self.position, self.z, self.yaw, self.speed, self.appear_at_s, *(self.size or ()),
                *(self.velocity or ()), *(c for w in self.waypoints or () for c in w), *(self.waits or ())]
        if not all(math.isfinite(x) for x in nums):
            raise ValueError("object numbers must be finite")
        if self.size is not None and min(self.size) <= 0:
            raise ValueError("object sizes must be positive")
        if self.waypoints is not None and len(self.waypoints) < 2:
            raise ValueError("waypoints need at least two points")
        if self.waits is not None and (self.waypoints is None or len(self.waits) != len(self.waypoints)
                                       or min(self.waits) < 0):
            raise ValueError("waits need waypoints: one non-negative duration (s) per waypoint")
        return self

    @property
    def label(self) -> int:
        if isinstance(self.class_, int):
            if not 0 <= self.class_ < ade20k.NUM_CLASSES:
                raise ValueError(f"class index {self.class_} is not an ADE20K index")
            return self.class_
        return ade20k.index(str(self.class_))


class MountSpec(_Model):
    """The scenario file's camera mount: the optical centre in the robot's base frame (m) and a pitch
    (degrees, > 0 looks down). What a scenario leaves out is the LIMO's (``LIMO.camera``), so the
    simulated camera sits where perception's default extrinsic says it does."""

    # The file has no roll or yaw: a forward camera on a ground robot only tilts.
    x: float = LIMO.camera.position[0]
    y: float = LIMO.camera.position[1]
    z: float = LIMO.camera.position[2]
    pitch_deg: float = Field(LIMO.camera.rpy_deg[1], ge=-89, le=89)


class CameraSpec(_Model):
    width: int = Field(512, gt=0, le=4096)
    height: int = Field(384, gt=0, le=4096)
    hfov_deg: float | None = Field(90.0, gt=1, lt=179)
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    mount: MountSpec = Field(default_factory=MountSpec)

    def pinhole(self) -> PinholeCamera:
        base = PinholeCamera.from_fov(self.width, self.height, self.hfov_deg or 90.0)
        return PinholeCamera(self.width, self.height, self.fx or base.fx, self.fy or self.fx or base.fy,
                             base.cx if self.cx is None else self.cx, base.cy if self.cy is None else self.cy)

    def camera_mount(self) -> CameraMount:
        """The mount as the platform description spells it (``geometry.camera.T_base_camera`` poses it)."""
        m = self.mount
        return CameraMount(position=(m.x, m.y, m.z), rpy_deg=(0.0, m.pitch_deg, 0.0))


class RobotSpec(_Model):
    type: str = "limo"
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    z: float = 0.0
    params: dict[str, float | str] = Field(default_factory=dict)

    @field_validator("type")
    @classmethod
    def _known(cls, v: str) -> str:
        resolve_robot_type(v)  # raises, naming the robot types there are
        return v


class Scenario(_Model):
    name: str = "scenario"
    room: RoomSpec | None = Field(default_factory=RoomSpec)
    procedural: ProceduralSpec | None = None
    objects: list[ObjectSpec] = Field(default_factory=list)
    robot: RobotSpec = Field(default_factory=RobotSpec)
    camera: CameraSpec = Field(default_factory=CameraSpec)
    goals: list[tuple[float, float]] = Field(default_factory=list)
    base_dir: str | None = Field(None, exclude=True)  # where relative mesh paths start


#: people walking in a ``random`` / ``random:SEED`` room (drawn after its other objects, which stay as
#: they were without walkers)
RANDOM_WALKERS = 2


def _builtin() -> dict[str, dict[str, Any]]:
    teleop = {"room": {"size": [8.0, 4.0]}, "robot": {"type": "limo", "start": [-3.0, 0.0, 0.0]}}
    return {
        "empty": {"name": "empty", "room": {"size": [6.0, 6.0]}},
        # The paper's teleoperation experiment: a LIMO facing a ball (low risk) or a dog (high risk).
        "teleop_ball": {**teleop, "name": "teleop_ball",
                        "objects": [{"class": "ball", "name": "ball", "position": [0.5, 0.0]}]},
        "teleop_dog": {**teleop, "name": "teleop_dog",
                       "objects": [{"class": "animal", "name": "dog", "position": [0.5, 0.0], "yaw": math.pi / 2}]},
        # The navigation loop: four corners of a 4 m square, a table in the middle, a chair and a
        # ball near the path, a person walking across it, and a box that appears on the path at 15 s.
        "navigation": {
            "name": "navigation", "room": {"size": [7.0, 7.0]},
            "robot": {"type": "limo", "start": [-2.0, -2.0, 0.0]},
            "goals": [[2.0, -2.0], [2.0, 2.0], [-2.0, 2.0], [-2.0, -2.0]],
            "objects": [
                {"class": "table", "name": "table", "position": [0.0, 0.0]},
                {"class": "chair", "name": "chair", "position": [2.8, 0.0], "yaw": math.pi},
                {"class": "ball", "name": "ball", "position": [0.0, 2.6]},
                {"class": "person", "name": "walker", "position": [-0.6, -3.0],
                 "waypoints": [[-0.6, -3.0], [-0.6, -1.2]], "speed": 0.4},
                {"class": "box", "name": "unseen_box", "position": [2.0, 0.6], "appear_at_s": 15.0},
            ],
        },
        "random": {"name": "random", "room": None, "procedural": {"seed": 0, "walkers": RANDOM_WALKERS}},
    }


BUILTIN: dict[str, dict[str, Any]] = _builtin()


def load_scenario(source: str | Path | dict[str, Any]) -> Scenario:
    """A scenario from a built-in name (``random:SEED`` for a procedural room with ``RANDOM_WALKERS``
    walkers), a YAML file path,
    or a dict. Raises ``ValueError``/``FileNotFoundError`` with the reason."""
    if isinstance(source, dict):
        return Scenario.model_validate(source)
    text = str(source)
    if text.startswith("random:"):
        seed = int(text.split(":", 1)[1])
        return Scenario.model_validate({"name": text, "room": None,
                                        "procedural": {"seed": seed, "walkers": RANDOM_WALKERS}})
    if text in BUILTIN:
        return Scenario.model_validate(BUILTIN[text])
    path = Path(text)
    if not path.is_file():
        raise FileNotFoundError(f"scenario {text!r} is neither a built-in ({', '.join(BUILTIN)}) nor a file")
    data = yaml.safe_load(path.read_text()) or {}
    if not isinstance(data, dict):
        raise ValueError(f"scenario file {path}: the top level must be a mapping")
    data.setdefault("name", path.stem)
    scenario = Scenario.model_validate(data)
    scenario.base_dir = str(path.parent)
    return scenario


def object_from_spec(spec: ObjectSpec, name: str, base_dir: str | None = None) -> SceneObject:
    """The scene object a spec describes (primitive or mesh file)."""
    pose = pose_matrix(spec.position[0], spec.position[1], spec.z + LIFT, spec.yaw)
    motion = None
    if spec.waypoints is not None or spec.velocity is not None:
        motion = Motion(np.asarray(spec.waypoints) if spec.waypoints else None, spec.speed, spec.motion,
                        spec.velocity or (0.0, 0.0), None if spec.waits is None else np.asarray(spec.waits))
    if spec.mesh is not None:
        path = Path(spec.mesh)
        if not path.is_absolute() and base_dir:
            path = Path(base_dir) / path
        obj = load_labelled_ply(path, names=spec.names).to_object(name, pose)
        obj.motion, obj.appear_at_s = motion, spec.appear_at_s
        return obj
    label = spec.label
    return SceneObject(name, label, procedural.object_mesh(ade20k.CLASSES[label], spec.size, spec.shape), pose,
                       motion=motion, appear_at_s=spec.appear_at_s)


def build_scene(scenario: Scenario) -> Scene:
    """The ``Scene`` of a scenario: room, procedural objects (if any), then listed objects."""
    objects: list[SceneObject] = []
    proc = scenario.procedural
    if scenario.room is not None:
        r = scenario.room
        objects += procedural.room(r.size[0], r.size[1], r.height, r.wall_thickness, r.ceiling)
        size = r.size
    elif proc is not None:
        rng = np.random.default_rng([proc.seed, 7])
        size = (float(rng.uniform(4.0, 8.0)), float(rng.uniform(4.0, 7.0)))
        objects += procedural.room(size[0], size[1])
    else:
        size = None
    if proc is not None and size is not None:
        sx, sy, _ = scenario.robot.start
        furnishing = procedural.Furnishing(proc.furniture, proc.boxes, proc.balls, proc.people, proc.animals,
                                           proc.walkers, proc.walker_speed)
        placements = procedural.random_placements(proc.seed, size[0], size[1], furnishing, keep_clear=(sx, sy, 0.8))
        objects += procedural.build_objects(placements, prefix="proc_")
    counts: dict[str, int] = {}
    for spec in scenario.objects:
        base = spec.name or (Path(spec.mesh).stem if spec.mesh else ade20k.CLASSES[spec.label].replace(" ", "_"))
        n = counts[base] = counts.get(base, 0) + 1
        name = spec.name or f"{base}_{n}"
        objects.append(object_from_spec(spec, name, scenario.base_dir))
    return Scene(objects)
