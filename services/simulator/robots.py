"""Robot kinematics for the simulator: the LIMO in its three motion modes, and the 3-D single and
double integrators of the paper's benchmark.

Every model takes the wire contract's velocity command — body-frame ``linear`` (m/s) and
``angular`` (rad/s) — through ``step(linear, angular, dt)`` and reports ``state()``: position,
orientation (quaternion xyzw), world-frame linear and angular velocity.

Commands are clamped to the platform's limits, then the actual velocity moves towards the
command no faster than the acceleration limits allow (a first-order actuator), and the pose is
integrated **exactly** for that velocity held constant over the step (zero-order hold): for a
constant body twist ``(vx, vy, ω)`` the SE(2) exponential is

    Δx_b = (vx·sin ωΔt − vy·(1 − cos ωΔt)) / ω,   Δy_b = (vx·(1 − cos ωΔt) + vy·sin ωΔt) / ω,

rotated into the world by the heading at the start of the step, and θ ← θ + ωΔt. With
``vy = 0`` this is the unicycle's arc of radius v/ω; with ω → 0 the straight line.

LIMO values (``LIMO``) come from ``riskfield.protocol.platforms.LIMO``, the one home of the
platform's figures (the bridge and the filter read them too; its docstring gives the sources):
about 1 m/s, in Ackermann mode a 0.2 m wheelbase and ±0.488 rad steering (0.4 m minimum turning
radius), |ω| ≤ 2 rad/s, |a| ≤ 1.5 m/s², |α| ≤ 6 rad/s². They are parameters; a real unit should be
measured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from riskfield.protocol.platforms import LIMO as PLATFORM

from ..geometry.transforms import wrap_angle, yaw_matrix, yaw_of, yaw_quaternion


@dataclass(frozen=True)
class KinematicState:
    """What the simulator publishes as ``RobotState``."""

    position: np.ndarray
    orientation: np.ndarray  # quaternion xyzw
    linear_velocity: np.ndarray  # world frame
    angular_velocity: np.ndarray  # world frame

    @property
    def yaw(self) -> float:
        return yaw_of(self.orientation)


class Robot(Protocol):
    def step(self, linear: np.ndarray, angular: np.ndarray, dt: float) -> None: ...

    def state(self) -> KinematicState: ...

    def pose(self) -> np.ndarray: ...


@dataclass(frozen=True)
class PlanarLimits:
    v_max: float = PLATFORM.max_linear  # |forward speed| (m/s)
    vy_max: float = 0.0  # |lateral speed| (m/s); > 0 only for mecanum
    w_max: float = PLATFORM.max_angular  # |yaw rate| (rad/s)
    a_max: float = PLATFORM.max_accel  # |linear acceleration| (m/s²)
    alpha_max: float = PLATFORM.max_yaw_accel  # |yaw acceleration| (rad/s²)


LIMO = PlanarLimits()
LIMO_MECANUM = PlanarLimits(vy_max=PLATFORM.max_lateral)
LIMO_WHEELBASE = PLATFORM.wheelbase
LIMO_MAX_STEER = PLATFORM.max_steering


def _towards(current: float, target: float, rate: float, dt: float) -> float:
    step = rate * dt
    return current + min(max(target - current, -step), step)


def _finite(x: np.ndarray | float) -> bool:
    return bool(np.all(np.isfinite(x)))


def se2_step(x: float, y: float, yaw: float, vx: float, vy: float, w: float, dt: float) -> tuple[float, float, float]:
    """Exact pose after moving with constant body twist ``(vx, vy, w)`` for ``dt``."""
    th = w * dt
    if abs(th) < 1e-9:
        # Second-order series of the exponential: exact to rounding for tiny rotations.
        dxb, dyb = vx * dt - 0.5 * vy * th * dt, vy * dt + 0.5 * vx * th * dt
    else:
        s, c1 = math.sin(th), 1.0 - math.cos(th)
        dxb, dyb = (vx * s - vy * c1) / w, (vx * c1 + vy * s) / w
    c, s = math.cos(yaw), math.sin(yaw)
    return x + c * dxb - s * dyb, y + s * dxb + c * dyb, wrap_angle(yaw + th)


@dataclass
class _Planar:
    """Shared state of the planar LIMO models: pose (x, y, yaw) on the floor at height ``z``
    and the actual body velocities."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    z: float = 0.0
    limits: PlanarLimits = field(default_factory=PlanarLimits)
    vx: float = 0.0
    vy: float = 0.0
    w: float = 0.0

    def _accelerate(self, vx: float, vy: float, w: float, dt: float) -> None:
        lim = self.limits
        self.vx = _towards(self.vx, float(np.clip(vx, -lim.v_max, lim.v_max)), lim.a_max, dt)
        self.vy = _towards(self.vy, float(np.clip(vy, -lim.vy_max, lim.vy_max)), lim.a_max, dt)
        self.w = _towards(self.w, float(np.clip(w, -lim.w_max, lim.w_max)), lim.alpha_max, dt)

    def _move(self, dt: float) -> None:
        self.x, self.y, self.yaw = se2_step(self.x, self.y, self.yaw, self.vx, self.vy, self.w, dt)

    def state(self) -> KinematicState:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return KinematicState(
            position=np.array([self.x, self.y, self.z]),
            orientation=yaw_quaternion(self.yaw),
            linear_velocity=np.array([c * self.vx - s * self.vy, s * self.vx + c * self.vy, 0.0]),
            angular_velocity=np.array([0.0, 0.0, self.w]),
        )

    def pose(self) -> np.ndarray:
        """4x4 body → world."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:3, 3] = (self.x, self.y, self.z)
        return T


@dataclass
class Unicycle(_Planar):
    """LIMO differential (four-wheel skid-steer) mode: ẋ = v cos θ, ẏ = v sin θ, θ̇ = ω.
    Uses ``linear[0]`` and ``angular[2]``; lateral commands are ignored (it cannot slide)."""

    def step(self, linear: np.ndarray, angular: np.ndarray, dt: float) -> None:
        if dt <= 0:
            return
        if not (_finite(linear) and _finite(angular)):
            linear, angular = np.zeros(3), np.zeros(3)  # fail safe: brake on garbage
        self._accelerate(float(linear[0]), 0.0, float(angular[2]), dt)
        self._move(dt)


@dataclass
class Ackermann(_Planar):
    """LIMO Ackermann mode as a kinematic bicycle: θ̇ = v·tan δ / L with |δ| ≤ ``max_steer``.

    The command's yaw rate is turned into the steering angle that would produce it at the
    commanded speed, δ = atan(ω L / v), clamped; the robot then turns at v·tan δ / L. It cannot
    turn in place: at v = 0 the yaw rate is 0."""

    wheelbase: float = LIMO_WHEELBASE
    max_steer: float = LIMO_MAX_STEER
    steer: float = 0.0

    def step(self, linear: np.ndarray, angular: np.ndarray, dt: float) -> None:
        if dt <= 0:
            return
        if not (_finite(linear) and _finite(angular)):
            linear, angular = np.zeros(3), np.zeros(3)
        v_cmd, w_cmd = float(linear[0]), float(angular[2])
        lim = self.limits
        self.vx = _towards(self.vx, float(np.clip(v_cmd, -lim.v_max, lim.v_max)), lim.a_max, dt)
        if abs(v_cmd) > 1e-6:
            self.steer = float(np.clip(math.atan(w_cmd * self.wheelbase / v_cmd), -self.max_steer, self.max_steer))
        self.w = self.vx * math.tan(self.steer) / self.wheelbase
        self.vy = 0.0
        self._move(dt)

    @property
    def min_turning_radius(self) -> float:
        return self.wheelbase / math.tan(self.max_steer)


@dataclass
class Mecanum(_Planar):
    """LIMO mecanum mode: independent body velocities vx, vy and yaw rate ω (holonomic)."""

    limits: PlanarLimits = field(default_factory=lambda: LIMO_MECANUM)

    def step(self, linear: np.ndarray, angular: np.ndarray, dt: float) -> None:
        if dt <= 0:
            return
        if not (_finite(linear) and _finite(angular)):
            linear, angular = np.zeros(3), np.zeros(3)
        self._accelerate(float(linear[0]), float(linear[1]), float(angular[2]), dt)
        self._move(dt)


@dataclass
class _Spatial:
    """Shared state of the 3-D point robots. ``yaw`` only turns the body (and its camera): the
    dynamics are those of a point. Body-frame commands are rotated by the yaw."""

    p: np.ndarray = field(default_factory=lambda: np.zeros(3))
    v: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0
    w: float = 0.0
    v_max: float = 2.0  # |velocity| (m/s), a norm bound
    w_max: float = 2.5

    def __post_init__(self) -> None:
        self.p = np.asarray(self.p, np.float64).copy()
        self.v = np.asarray(self.v, np.float64).copy()

    def _rot(self) -> np.ndarray:
        return yaw_matrix(self.yaw)

    def _turn(self, w_cmd: float, dt: float) -> None:
        self.w = float(np.clip(w_cmd, -self.w_max, self.w_max))
        self.yaw = wrap_angle(self.yaw + self.w * dt)

    def state(self) -> KinematicState:
        return KinematicState(self.p.copy(), yaw_quaternion(self.yaw), self.v.copy(), np.array([0.0, 0.0, self.w]))

    def pose(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self._rot()
        T[:3, 3] = self.p
        return T


def _clip_norm(x: np.ndarray, bound: float) -> np.ndarray:
    n = float(np.linalg.norm(x))
    return x * (bound / n) if n > bound else x


@dataclass
class SingleIntegrator(_Spatial):
    """ṗ = u with u the commanded velocity (rotated by the yaw), |u| ≤ ``v_max``."""

    def step(self, linear: np.ndarray, angular: np.ndarray, dt: float) -> None:
        if dt <= 0:
            return
        if not (_finite(linear) and _finite(angular)):
            linear, angular = np.zeros(3), np.zeros(3)
        self.v = _clip_norm(self._rot() @ np.asarray(linear, np.float64), self.v_max)
        self.p = self.p + self.v * dt
        self._turn(float(angular[2]), dt)


@dataclass
class DoubleIntegrator(_Spatial):
    """The paper's benchmark robot: ṗ = v, v̇ = u, integrated exactly for u held over the step
    (p += vΔt + ½uΔt², v += uΔt), |u| ≤ ``a_max``, then |v| ≤ ``v_max``.

    ``input = "acceleration"``: the command's ``linear`` *is* u (body frame, rotated by the yaw).
    ``input = "velocity"``: ``linear`` is a velocity set-point tracked by u = k_v·(v_cmd − v),
    so the same velocity commands that drive a LIMO drive it too."""

    a_max: float = 3.0
    input: str = "velocity"
    k_v: float = 4.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.input not in ("velocity", "acceleration"):
            raise ValueError(f"double integrator input {self.input!r}: use velocity or acceleration")

    def step(self, linear: np.ndarray, angular: np.ndarray, dt: float) -> None:
        if dt <= 0:
            return
        if not (_finite(linear) and _finite(angular)):
            linear, angular = np.zeros(3), np.zeros(3)
        cmd = self._rot() @ np.asarray(linear, np.float64)
        u = cmd if self.input == "acceleration" else self.k_v * (cmd - self.v)
        u = _clip_norm(u, self.a_max)
        self.p = self.p + self.v * dt + 0.5 * u * dt * dt
        self.v = _clip_norm(self.v + u * dt, self.v_max)
        self._turn(float(angular[2]), dt)


ROBOT_TYPES = ("limo", "ackermann", "mecanum", "single_integrator", "double_integrator")


def make_robot(kind: str, start: tuple[float, float, float] = (0.0, 0.0, 0.0), z: float = 0.0, **params: float | str
               ) -> Robot:
    """A robot of ``kind`` (see ``ROBOT_TYPES``) at floor pose ``start = (x, y, yaw)``.

    ``params`` override limits: ``v_max, w_max, a_max, alpha_max, vy_max`` for the LIMO modes,
    ``v_max, w_max, a_max, input, k_v`` for the integrators."""
    x, y, yaw = (float(c) for c in start)
    if kind in ("limo", "ackermann", "mecanum"):
        base = LIMO_MECANUM if kind == "mecanum" else LIMO
        extra = {k: params.pop(k) for k in ("wheelbase", "max_steer") if k in params}
        limits = PlanarLimits(**{**base.__dict__, **params})  # type: ignore[arg-type]
        cls = {"limo": Unicycle, "ackermann": Ackermann, "mecanum": Mecanum}[kind]
        if extra and cls is not Ackermann:
            raise ValueError(f"{sorted(extra)} only apply to the ackermann robot")
        return cls(x=x, y=y, yaw=yaw, z=z, limits=limits, **extra)  # type: ignore[arg-type]
    if kind == "single_integrator":
        return SingleIntegrator(p=np.array([x, y, z]), yaw=yaw, **params)  # type: ignore[arg-type]
    if kind == "double_integrator":
        return DoubleIntegrator(p=np.array([x, y, z]), yaw=yaw, **params)  # type: ignore[arg-type]
    raise ValueError(f"unknown robot type {kind!r}; use one of {', '.join(ROBOT_TYPES)}")
