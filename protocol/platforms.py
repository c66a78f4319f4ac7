"""Robot platforms: one description per robot — footprint, kinematics, limits, camera mount.

Everything that models a robot reads its description from here: for the LIMO the serial bridge's
command limits (``edge/limo/kinematics.LimoLimits``), the chassis emulator (``edge/limo/emulator``),
the simulator's plants (``services/simulator/robots``), the safety filter's unicycle (its footprint
and input bounds, ``services/safety_filter/config``), the navigator's limits and perception's camera
extrinsics; for a multicopter the MAVLink bridge's setpoint limits; for the paper's point robot the
simulator's integrators. The Ackermann geometry (central ↔ inner wheel angle) lives here too,
because the simulator and the bridge both steer with it. It lives in the wire-contract package
because both ``edge/`` and ``services/`` may import it, and an
external client modelling the robot can too (pydantic only).

Sources, and which value is used where they disagree:

* body 0.322 × 0.220 m. Trossen's copy of the LIMO documentation
  (``TrossenRobotics/agilex_limo_docs``, ``specifications/limo.rst``) lists 322 × 215 × 247 mm;
  the wider figure is the conservative one for a barrier.
* wheelbase 0.2 m, track 0.172 m, inner-wheel steering ±0.488 rad (central ~0.408 rad, minimum
  turning radius ~0.46 m; AgileX's pylimo has 0.48869), about 1 m/s no-load:
  ``shared/reference/hardware_and_zenoh.md``. (AgileX's ROS driver, ``agilexrobotics/
  limo_ros`` ``limo_base/include/limo_base/limo_params.h``, has track 0.176 m and a 1.5 m/s
  ``max_linear_speed`` that its ``limo_driver.cpp`` never applies; the reference's figures are used.)
* yaw rate 2.0 rad/s: no datasheet gives one (the chassis itself only bounds wheel speed, so
  differential ω could reach 2·1.0/0.172 ≈ 11.6 rad/s); the bridge, the simulator and the filter
  all use this one figure.
* camera mount 0.15 m forward, 0.1 m up, looking ahead (``CameraMount``): the simulator's LIMO
  camera (scenarios default to this one); no datasheet gives the real unit's, so a bring-up
  measures it (docs/deployment.md) and sets ``camera`` in the platform description.
* acceleration 1.5 m/s², yaw acceleration 6 rad/s²: no datasheet figure either; the simulator's
  gentle first-order actuator for a 4.2 kg robot. A real unit should be measured. The filter's
  unicycle plans with these 1.5 m/s² (its gain cap 2 a / v stays above every default risk group's gain).
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]

#: How a wheeled ground robot turns its body velocity command into motion: ``differential`` (skid
#: steer: forward speed and yaw rate), ``ackermann`` (front wheels steer: forward speed and
#: curvature), ``mecanum`` (holonomic: forward, lateral speed and yaw rate).
PlanarKinematics = Literal["differential", "ackermann", "mecanum"]
#: A vehicle controlled as a 3-D point with a heading: ``single_integrator`` takes a velocity,
#: ``double_integrator`` an acceleration (the paper's benchmark robot).
SpatialKinematics = Literal["single_integrator", "double_integrator"]


def central_to_inner(central: float, wheelbase: float, track: float) -> float:
    """Ackermann geometry: the inner front wheel's angle for a central (bicycle) angle, with its sign.

    AgileX's limo_ros ``limo_base/src/limo_driver.cpp`` ``convertCentralAngleToInner``:
    i = atan(2L sin|c| / (2L cos|c| − T sin|c|)). ``atan2`` gives the same angle while the
    denominator is positive and stays monotonic past it (|c| ≥ atan(2L/T), far beyond any steering
    limit), where ``atan`` would flip sign."""
    s, c = math.sin(abs(central)), math.cos(abs(central))
    inner = math.atan2(2 * wheelbase * s, 2 * wheelbase * c - track * s)
    return math.copysign(inner, central) if central else 0.0


def inner_to_central(inner: float, wheelbase: float, track: float) -> float:
    """Ackermann geometry: the central (bicycle) angle for an inner wheel angle, with its sign.

    limo_driver.cpp ``convertInnerAngleToCentral``: r = L / tan|i| + T/2, c = atan(L / r).
    At i = 0 the C code divides by zero into r = ∞ and c = 0; here that is explicit."""
    if inner == 0.0:
        return 0.0
    r = wheelbase / math.tan(abs(inner)) + track / 2
    return math.copysign(math.atan(wheelbase / r), inner)


def min_turning_radius(wheelbase: float, track: float, max_inner: float) -> float:
    """Ackermann geometry: the rear axle centre's radius at the inner wheel's limit, L / tan|i| + T/2."""
    return wheelbase / math.tan(max_inner) + track / 2


def ackermann_steerable(v: float, w: float, max_curvature: float, min_speed: float) -> tuple[float, float]:
    """The (speed, yaw rate) an Ackermann chassis drives for the command (v, ω), before any speed
    limit: a curvature beyond ``max_curvature`` becomes the limit's at the same speed (the tightest
    circle it can steer), and below ``min_speed`` it cannot turn (ω = 0). The LIMO bridge drives
    this (``edge/limo/kinematics.ackermann_velocity``); the safety filter certifies it
    (``services/safety_filter/supervisor``), so the path the filter checked is the path driven."""
    if abs(v) < min_speed:
        return v, 0.0
    return v, v * max(-max_curvature, min(max_curvature, w / v))


class CameraMount(BaseModel):
    """Where the camera sits on the robot (REP 105's ``base_link``: x forward, y left, z up): the
    optical centre's position and the optical axis's roll, pitch (> 0 looks down) and yaw. Perception
    poses the camera in the odometry frame as ``T_odom_base · T_base_camera`` with it (the simulator
    renders from the same pose; ``services/geometry/camera.T_base_camera``), and its height above the
    floor scales SLAM's world before the robot has moved."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: tuple[float, float, float] = Field((0.15, 0.0, 0.1), description="optical centre in base_link (m)")
    rpy_deg: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description=(
        "roll, pitch, yaw of the optical axis in base_link (degrees; pitch > 0 looks down)"))
    height_sigma: Annotated[float, Field(ge=0, allow_inf_nan=False)] = Field(0.002, description=(
        "standard deviation (m) of the measured height: the floor plane's scale is no better than this"))

    @property
    def height(self) -> float:
        """The optical centre above the floor (m): base_link lies on the floor (z = 0)."""
        return self.position[2]


class PlanarPlatform(BaseModel):
    """A wheeled ground robot: body rectangle, wheel geometry, motion modes, motion limits and camera
    mount (SI units). The simulator's plants, the safety filter's body and bounds, the navigator and
    the LIMO bridge are built from one of these."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    kinematics: tuple[PlanarKinematics, ...] = Field(min_length=1, description=(
        "the motion modes the chassis drives, its default first"))
    length: Pos = Field(description="body length along x (m)")
    width: Pos = Field(description="body width along y (m)")
    wheelbase: Pos = Field(description="front-to-rear axle distance (m)")
    track: Pos = Field(description="left-to-right wheel distance (m)")
    max_linear: Pos = Field(description="|forward speed| (m/s)")
    max_lateral: Pos = Field(description="|lateral speed| in mecanum mode (m/s)")
    max_angular: Pos = Field(description="|yaw rate| (rad/s)")
    max_wheel_speed: Pos = Field(description="|speed| of any wheel (m/s)")
    max_steering: Pos = Field(description=(
        "|inner front wheel's steering angle| in Ackermann mode (rad); the central angle's limit follows from "
        "it, the wheelbase and the track (edge/limo/ackermann.py: ~0.408 rad, radius ~0.46 m for the LIMO)"))
    max_accel: Pos = Field(description="|linear acceleration| (m/s²)")
    max_yaw_accel: Pos = Field(description="|yaw acceleration| (rad/s²)")
    min_steering_speed: Pos = Field(1e-3, description=(
        "below this |speed| (m/s) an Ackermann chassis cannot turn: its steering is straight"))
    camera: CameraMount = Field(default_factory=CameraMount, description="the camera's extrinsics in base_link")

    @property
    def max_central_steering(self) -> float:
        """|central (bicycle) angle| at the inner wheel's limit: the kinematic bicycle's steering limit."""
        return inner_to_central(self.max_steering, self.wheelbase, self.track)

    @property
    def min_turning_radius(self) -> float:
        """Radius of the rear axle's centre at the steering limit (Ackermann)."""
        return min_turning_radius(self.wheelbase, self.track, self.max_steering)

    @property
    def max_curvature(self) -> float:
        """1 / ``min_turning_radius``: the tightest curvature (1/m) it steers in Ackermann mode."""
        return 1.0 / self.min_turning_radius


class SpatialPlatform(BaseModel):
    """A vehicle controlled as a 3-D point with a heading (a multicopter behind its autopilot, the
    paper's benchmark robot): speed, climb, yaw-rate and acceleration limits (SI units)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    kinematics: tuple[SpatialKinematics, ...] = Field(min_length=1, description=(
        "how it is commanded, its default first"))
    max_speed: Pos = Field(description="|velocity| (m/s): a norm bound; an autopilot's horizontal one")
    max_vertical: Pos = Field(description="|vertical speed| (m/s)")
    max_yaw_rate: Pos = Field(description="|yaw rate| (rad/s)")
    max_accel: Pos | None = Field(description=(
        "|acceleration| (m/s²), a norm bound; None: the autopilot's own, not commanded here"))

    @model_validator(mode="after")
    def _climb_within_speed(self) -> SpatialPlatform:
        if self.max_vertical > self.max_speed:
            raise ValueError("max_vertical exceeds max_speed, the norm bound")
        return self


Platform = PlanarPlatform | SpatialPlatform


#: The AgileX LIMO (see the module docstring for where each figure comes from).
LIMO = PlanarPlatform(
    name="limo", kinematics=("differential", "ackermann", "mecanum"),
    length=0.322, width=0.220, wheelbase=0.2, track=0.172,
    max_linear=1.0, max_lateral=1.0, max_angular=2.0, max_wheel_speed=1.0, max_steering=0.488,
    max_accel=1.5, max_yaw_accel=6.0,
)

#: The paper's benchmark robot: a point mass with a heading, |v| ≤ 2 m/s, |a| ≤ 3 m/s², the
#: simulator's integrators (the filter's ``single3d`` / ``double3d`` models take their own bounds).
POINT_MASS = SpatialPlatform(
    name="point_mass", kinematics=("double_integrator", "single_integrator"),
    max_speed=2.0, max_vertical=2.0, max_yaw_rate=2.5, max_accel=3.0,
)

#: A multicopter behind a MAVLink autopilot, as the bridge bounds its velocity setpoints: 1 m/s
#: horizontally, 0.5 m/s vertically, 1 rad/s of yaw (the bridge's first-flight figures, not a datasheet's);
#: the autopilot limits its own acceleration.
MULTICOPTER = SpatialPlatform(
    name="multicopter", kinematics=("single_integrator",),
    max_speed=1.0, max_vertical=0.5, max_yaw_rate=1.0, max_accel=None,
)

#: Every description by name. A new robot is one more entry here (plus, for a new way of moving,
#: one kinematics function in the simulator, ``services/simulator/robots.KINEMATICS``).
PLATFORMS: dict[str, Platform] = {p.name: p for p in (LIMO, POINT_MASS, MULTICOPTER)}


def platform(name: str) -> Platform:
    """The description called ``name``; an unknown name is an error listing the known ones."""
    try:
        return PLATFORMS[name]
    except KeyError:
        raise ValueError(f"unknown platform {name!r}; use one of {', '.join(PLATFORMS)}") from None
