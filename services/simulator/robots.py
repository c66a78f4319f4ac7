"""The simulator's plants: a robot's motion, built from its platform description
(``riskfield.protocol.platforms``) and one kinematics function per way of moving (``KINEMATICS``):
``DifferentialPlant``, ``AckermannPlant`` and ``MecanumPlant`` for a wheeled ground robot such as the
LIMO in its three motion modes, ``VelocityPointPlant`` and ``PointMassPlant`` for the paper's 3-D
point robot. They are plants (what moves), named apart from the safety filter's barrier models
(what it plans with, ``safety_filter.barriers``).

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

Every figure comes from the platform's description (``protocol.platforms``, which gives the
sources): the limits, the wheelbase and, for Ackermann steering, the *central* (bicycle) angle's
limit, which follows from the inner wheel's mechanical limit, the wheelbase and the track
(``PlanarPlatform.max_central_steering``, the conversion the LIMO bridge uses). A robot type is
``PLATFORM`` or ``PLATFORM:KINEMATICS`` (``limo:ackermann``); the names ``limo``, ``ackermann``,
``mecanum``, ``single_integrator`` and ``double_integrator`` stay as they were (``ROBOT_TYPES``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from riskfield.protocol.platforms import LIMO as LIMO_PLATFORM
from riskfield.protocol.platforms import PLATFORMS, POINT_MASS, PlanarPlatform, SpatialPlatform, platform

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
    v_max: float = LIMO_PLATFORM.max_linear  # |forward speed| (m/s)
    vy_max: float = 0.0  # |lateral speed| (m/s); > 0 only for mecanum
    w_max: float = LIMO_PLATFORM.max_angular  # |yaw rate| (rad/s)
    a_max: float = LIMO_PLATFORM.max_accel  # |linear acceleration| (m/s²)
    alpha_max: float = LIMO_PLATFORM.max_yaw_accel  # |yaw acceleration| (rad/s²)

    @classmethod
    def of(cls, p: PlanarPlatform, lateral: bool = False) -> PlanarLimits:
        """A platform's limits; ``lateral``: it may slide sideways (mecanum)."""
        return cls(p.max_linear, p.max_lateral if lateral else 0.0, p.max_angular, p.max_accel, p.max_yaw_accel)


LIMO = PlanarLimits.of(LIMO_PLATFORM)
LIMO_MECANUM = PlanarLimits.of(LIMO_PLATFORM, lateral=True)


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
class DifferentialPlant(_Planar):
    """Differential (four-wheel skid-steer) drive, the LIMO's default mode: ẋ = v cos θ, ẏ = v sin θ, θ̇ = ω.
    Uses ``linear[0]`` and ``angular[2]``; lateral commands are ignored (it cannot slide)."""

    def step(self, linear: np.ndarray, angular: np.ndarray, dt: float) -> None:
        if dt <= 0:
            return
        if not (_finite(linear) and _finite(angular)):
            linear, angular = np.zeros(3), np.zeros(3)  # fail safe: brake on garbage
        self._accelerate(float(linear[0]), 0.0, float(angular[2]), dt)
        self._move(dt)


@dataclass
class AckermannPlant(_Planar):
    """Ackermann steering as a kinematic bicycle: θ̇ = v·tan δ / L with |δ| ≤ ``max_steer``, the
    central angle's limit (``PlanarPlatform.max_central_steering``, where the inner wheel reaches its
    ``max_steering``: a tighter limit than that one).

    The command's yaw rate is turned into the steering angle that would produce it at the
    commanded speed, δ = atan(ω L / v), clamped; the robot then turns at v·tan δ / L. It cannot
    turn in place: at v = 0 the yaw rate is 0."""

    wheelbase: float = LIMO_PLATFORM.wheelbase
    max_steer: float = LIMO_PLATFORM.max_central_steering
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
class MecanumPlant(_Planar):
    """Mecanum wheels: independent body velocities vx, vy and yaw rate ω (holonomic)."""

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
    v_max: float = POINT_MASS.max_speed  # |velocity| (m/s), a norm bound
    w_max: float = POINT_MASS.max_yaw_rate

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
class VelocityPointPlant(_Spatial):
    """A velocity-controlled point (single integrator): ṗ = u with u the commanded velocity (rotated
    by the yaw), |u| ≤ ``v_max``."""

    def step(self, linear: np.ndarray, angular: np.ndarray, dt: float) -> None:
        if dt <= 0:
            return
        if not (_finite(linear) and _finite(angular)):
            linear, angular = np.zeros(3), np.zeros(3)
        self.v = _clip_norm(self._rot() @ np.asarray(linear, np.float64), self.v_max)
        self.p = self.p + self.v * dt
        self._turn(float(angular[2]), dt)


@dataclass
class PointMassPlant(_Spatial):
    """The paper's benchmark robot, a point mass (double integrator): ṗ = v, v̇ = u, integrated
    exactly for u held over the step (p += vΔt + ½uΔt², v += uΔt), |u| ≤ ``a_max``, then |v| ≤ ``v_max``.

    ``input = "acceleration"``: the command's ``linear`` *is* u (body frame, rotated by the yaw).
    ``input = "velocity"``: ``linear`` is a velocity set-point tracked by u = k_v·(v_cmd − v),
    so the same velocity commands that drive a LIMO drive it too."""

    a_max: float = POINT_MASS.max_accel  # type: ignore[assignment]  # the point mass has one
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


#: One kinematics function per way of moving, by the platforms' kinematics names.
KINEMATICS: dict[str, type[_Planar] | type[_Spatial]] = {
    "differential": DifferentialPlant, "ackermann": AckermannPlant, "mecanum": MecanumPlant,
    "single_integrator": VelocityPointPlant, "double_integrator": PointMassPlant,
}

#: The robot types scenarios have always named, as ``(platform, kinematics)``.
NAMED_TYPES: dict[str, tuple[str, str]] = {
    "limo": ("limo", "differential"), "ackermann": ("limo", "ackermann"), "mecanum": ("limo", "mecanum"),
    "single_integrator": ("point_mass", "single_integrator"), "double_integrator": ("point_mass", "double_integrator"),
}
ROBOT_TYPES = tuple(NAMED_TYPES)


def resolve_robot_type(kind: str) -> tuple[PlanarPlatform | SpatialPlatform, str]:
    """``kind`` (a name of ``ROBOT_TYPES``, ``PLATFORM`` or ``PLATFORM:KINEMATICS``) as its platform
    description and kinematics; an unknown one is an error that lists what there is."""
    name, _, kin = kind.partition(":")
    if kind in NAMED_TYPES:
        name, kin = NAMED_TYPES[kind]
    elif name not in PLATFORMS:
        raise ValueError(f"unknown robot type {kind!r}; use one of {', '.join(ROBOT_TYPES)}, or PLATFORM[:KINEMATICS] "
                         f"with a platform of {', '.join(PLATFORMS)}")
    p = platform(name)
    kin = kin or p.kinematics[0]
    if kin not in p.kinematics:
        raise ValueError(f"robot type {kind!r}: {name} drives {', '.join(p.kinematics)}, not {kin}")
    return p, kin


def make_robot(kind: str, start: tuple[float, float, float] = (0.0, 0.0, 0.0), z: float = 0.0, **params: float | str
               ) -> Robot:
    """A robot of ``kind`` (``resolve_robot_type``) at floor pose ``start = (x, y, yaw)``, built from
    its platform's description.

    ``params`` override limits: ``v_max, w_max, a_max, alpha_max, vy_max`` (and ``wheelbase,
    max_steer`` for Ackermann, the central angle's limit) for a ground robot, ``v_max, w_max, a_max,
    input, k_v`` for a point robot."""
    x, y, yaw = (float(c) for c in start)
    p, kin = resolve_robot_type(kind)
    cls = KINEMATICS[kin]
    if isinstance(p, PlanarPlatform):
        base = PlanarLimits.of(p, lateral=kin == "mecanum")
        extra = {k: params.pop(k) for k in ("wheelbase", "max_steer") if k in params}
        limits = PlanarLimits(**{**base.__dict__, **params})  # type: ignore[arg-type]
        if extra and cls is not AckermannPlant:
            raise ValueError(f"{sorted(extra)} only apply to an ackermann robot")
        if cls is AckermannPlant:
            extra = {"wheelbase": p.wheelbase, "max_steer": p.max_central_steering, **extra}
        return cls(x=x, y=y, yaw=yaw, z=z, limits=limits, **extra)  # type: ignore[arg-type,call-arg]
    defaults: dict[str, float | str] = {"v_max": p.max_speed, "w_max": p.max_yaw_rate}
    if cls is PointMassPlant and p.max_accel is not None:
        defaults["a_max"] = p.max_accel
    return cls(p=np.array([x, y, z]), yaw=yaw, **{**defaults, **params})  # type: ignore[arg-type,call-arg]
