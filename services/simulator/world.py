"""The simulated world: a scenario's scene, robot and camera advanced together in time.

Pure and clock-free: the caller says how much time passes (``advance``) and when commands
arrive (``command``); the node maps wall time onto it. Physics runs in fixed sub-steps of
``physics_dt``. A command older than ``watchdog_s`` is replaced by zero (the robot brakes at
its acceleration limits), like the LIMO bridge's watchdog.
"""

from __future__ import annotations

import math

import numpy as np

from riskfield.protocol import SimActor, ade20k

from ..geometry.camera import T_base_camera
from .camera import Render, Renderer
from .robots import KinematicState, Robot, make_robot
from .scenario import ObjectSpec, Scenario, build_scene, load_scenario, object_from_spec
from .scene import LIFT, Scene, Snapshot

#: Labels that are free space for a robot, never obstacles (ground-truth clearance ignores them).
_FREE = {ade20k.index("floor"), ade20k.index("ceiling"), ade20k.index("rug")}


class World:
    def __init__(self, scenario: Scenario | str, *, physics_dt: float = 0.005, watchdog_s: float = 0.2):
        if physics_dt <= 0 or watchdog_s <= 0:
            raise ValueError("physics_dt and watchdog_s must be positive")
        self.scenario = load_scenario(scenario) if isinstance(scenario, str) else scenario
        self.scene: Scene = build_scene(self.scenario)
        r = self.scenario.robot
        self.robot: Robot = make_robot(r.type, r.start, r.z, **dict(r.params))
        self.camera = self.scenario.camera.pinhole()
        self.renderer = Renderer(self.camera)
        self.T_BC = T_base_camera(self.scenario.camera.camera_mount())
        self.physics_dt = physics_dt
        self.watchdog_s = watchdog_s
        self.t = 0.0
        self._linear = np.zeros(3)
        self._angular = np.zeros(3)
        self._cmd_t = -math.inf
        self.watchdog_trips = 0
        self._tripped = False
        self._spawned = 0
        self._obstacles: Scene | None = None

    # -- input ----------------------------------------------------------------------------------
    def command(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """The latest velocity command (body frame), valid from now for ``watchdog_s``."""
        lin, ang = np.asarray(linear, np.float64), np.asarray(angular, np.float64)
        if lin.shape != (3,) or ang.shape != (3,) or not (np.isfinite(lin).all() and np.isfinite(ang).all()):
            raise ValueError("a command needs finite linear[3] and angular[3]")
        self._linear, self._angular, self._cmd_t = lin, ang, self.t
        self._tripped = False

    def add_object(self, spec: ObjectSpec | dict) -> str:
        """Add an object while running (an unseen obstacle); it appears now unless its
        ``appear_at_s`` is later. Returns its name."""
        spec = spec if isinstance(spec, ObjectSpec) else ObjectSpec.model_validate(spec)
        self._spawned += 1
        name = spec.name or f"spawned_{self._spawned}"
        if spec.appear_at_s < self.t:
            spec = spec.model_copy(update={"appear_at_s": self.t})
        self.scene.add(object_from_spec(spec, name, self.scenario.base_dir))
        return name

    # -- time -------------------------------------------------------------------------------------
    def advance(self, duration: float) -> None:
        """Integrate the robot for ``duration`` seconds in sub-steps of at most ``physics_dt``."""
        if not math.isfinite(duration) or duration <= 0:
            return
        n = max(1, math.ceil(duration / self.physics_dt - 1e-9))
        dt = duration / n
        for _ in range(n):
            if self.t - self._cmd_t > self.watchdog_s:
                if not self._tripped and math.isfinite(self._cmd_t):
                    self.watchdog_trips += 1
                self._tripped = True
                lin, ang = np.zeros(3), np.zeros(3)
            else:
                lin, ang = self._linear, self._angular
            self.robot.step(lin, ang, dt)
            self.t += dt

    # -- output -------------------------------------------------------------------------------
    def state(self) -> KinematicState:
        return self.robot.state()

    def T_WC(self) -> np.ndarray:
        """Camera → world now."""
        return self.robot.pose() @ self.T_BC

    def snapshot(self) -> Snapshot:
        return self.scene.at(self.t)

    def actors(self) -> list[SimActor]:
        """Ground truth of the present objects that move (``motion``): footprint centre at floor
        height, floor velocity, the radius and height of the upright cylinder holding the mesh."""
        out = []
        for o in self.scene.objects:
            if o.motion is None or not o.present(self.t):
                continue
            T, v = o.state_at(self.t)
            out.append(SimActor(name=o.name, label=int(o.label), position=(float(T[0, 3]), float(T[1, 3]),
                                                                           float(T[2, 3] - LIFT)),
                                velocity=(float(v[0]), float(v[1]), 0.0), radius=o.footprint_radius,
                                height=o.height))
        return out

    def render(self) -> Render:
        return self.renderer.render(self.snapshot(), self.T_WC())

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """Ground-truth signed distance from points to the nearest obstacle surface, ignoring
        free surfaces (floor, ceiling): what a collision check of the robot needs."""
        wanted = [o for o in self.scene.objects if o.label not in _FREE]
        if self._obstacles is None or [id(o) for o in self._obstacles.objects] != [id(o) for o in wanted]:
            self._obstacles = Scene(wanted)
        return self._obstacles.at(self.t).signed_distance(points)
