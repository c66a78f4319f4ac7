"""LIMO kinematics: body velocity command → motion frame per motion mode, and wheel odometry.

Command side
------------
A ``cmd/safe`` command is a body-frame velocity (vx forward, vy left, ωz counter-clockwise).
The chassis executes it differently per motion mode:

* **differential** (four-wheel skid steer): linear = vx, angular = ωz; vy cannot be executed.
* **Ackermann** (front wheels steer, rear axle fixed): linear = vx, angular = 0, and the steering
  field AgileX's driver sends: the curvature κ = ωz/vx gives the central (bicycle) angle
  c = atan(κ·L), the inner wheel's angle i follows from the geometry and the field is i / 1.64
  (``ackermann``). ``max_steering`` bounds the *inner* wheel; the central limit and the minimum
  turning radius (``PlanarPlatform.min_turning_radius``) follow from it, the wheelbase and the
  track. At (near) zero speed the chassis cannot turn: the wheels stay straight and ωz is dropped.
* **mecanum**: linear = vx, lateral = vy, angular = ωz.

Limits are applied by **scaling the whole command by one factor λ ∈ [0, 1]**, never by
clipping each axis on its own. Reason: the safety filter's barrier condition is affine in
the input, ``a(x)·u ≥ −α h(x)``; with h ≥ 0 the zero input satisfies it, so every λu between
the filtered u and zero still does. Clipping one axis (say ω but not v) would change the
direction of motion and could leave the safe set. λ also keeps every wheel below its speed
limit: for a differential or mecanum base the fastest wheel moves at |vx| + |vy| + |ωz|·r
with r = track/2 (plus wheelbase/2 for mecanum rollers).

The one clamp that is not a scaling is the Ackermann steering limit, because no λ changes a
curvature: a command asking for a tighter turn than the chassis can steer is driven on the
tightest circle instead, at the commanded speed (ω = vx·κ_max, the path the wheels will take),
and the speed limits then scale (vx, ω) together, so the radius stays the limit's.

Odometry side
-------------
``WheelOdometry`` dead-reckons a planar pose from the cumulative left/right wheel travel of
the ``0x311`` frames: forward travel ds = (dl + dr)/2, rotation dθ = (dr − dl)/track, the
midpoint rule x += ds·cos(θ + dθ/2). When the IMU yaw (``0x323``) is present it replaces the
wheel heading (skid-steer wheels slip when turning; the IMU does not), relative to the yaw
seen first so the map frame starts at the robot's initial pose with heading 0.
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from riskfield.protocol.platforms import LIMO, PlanarPlatform
from riskfield.protocol.platforms import ackermann_steerable as steerable
from riskfield.services.geometry.transforms import wrap_angle

from . import ackermann
from .protocol import MotionCommand

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class MotionMode(IntEnum):
    DIFFERENTIAL = 0
    ACKERMANN = 1
    MECANUM = 2

    @classmethod
    def parse(cls, value: str | int) -> MotionMode:
        if isinstance(value, str) and not value.isdigit():
            return cls[value.strip().upper()]
        return cls(int(value))


class LimoLimits(BaseModel):
    """The limits every command is scaled into (SI), defaults from ``protocol.platforms.LIMO``."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    max_linear: Pos = Field(default=LIMO.max_linear, description="|forward speed| (m/s)")
    max_lateral: Pos = Field(default=LIMO.max_lateral, description="|lateral speed|, mecanum mode (m/s)")
    max_angular: Pos = Field(default=LIMO.max_angular, description="|yaw rate| (rad/s)")
    max_wheel_speed: Pos = Field(default=LIMO.max_wheel_speed, description="|speed| of any wheel (m/s)")
    max_steering: Pos = Field(default=LIMO.max_steering, description=(
        "|inner front wheel's steering angle|, Ackermann (rad); the central angle's limit and the minimum "
        "turning radius follow from it, the wheelbase and the track"))
    wheelbase: Pos = Field(default=LIMO.wheelbase, description="axle distance (m)")
    track: Pos = Field(default=LIMO.track, description="wheel distance left to right (m)")
    min_speed_for_steering: Pos = Field(default=LIMO.min_steering_speed, description=(
        "below this |speed| (m/s) an Ackermann chassis cannot turn: the steering is 0"))

    @classmethod
    def of(cls, p: PlanarPlatform, **overrides: float) -> LimoLimits:
        """Another ground robot's limits (the LIMO's are the defaults)."""
        names = ("max_linear", "max_lateral", "max_angular", "max_wheel_speed", "max_steering", "wheelbase", "track")
        return cls(**{**{n: getattr(p, n) for n in names}, **overrides})

    @property
    def max_central_steering(self) -> float:
        """|central (bicycle) angle| at the inner wheel's limit (``PlanarPlatform.max_central_steering``)."""
        return ackermann.max_central_angle(self.wheelbase, self.track, self.max_steering)

    @property
    def max_curvature(self) -> float:
        """1 / the minimum turning radius of the rear axle's centre (``PlanarPlatform.min_turning_radius``)."""
        return 1.0 / ackermann.min_turning_radius(self.wheelbase, self.track, self.max_steering)


def _scale(limits: list[tuple[float, float]]) -> float:
    """Largest λ ≤ 1 with λ·|value| ≤ bound for every (value, bound)."""
    lam = 1.0
    for value, bound in limits:
        if abs(value) > bound:
            lam = min(lam, bound / abs(value))
    return lam


def steering_angle(vx: float, wz: float, limits: LimoLimits) -> float:
    """Central (bicycle) steering angle that drives curvature ωz/vx, clamped to the limit.

    δ = atan(ωz·L/vx) keeps its sign convention when reversing: backing up with ωz > 0 needs
    the wheels turned right (δ < 0), which the formula gives because vx < 0 (AgileX's
    ``twistCmdCallback`` takes r = v/ω and atan(L/r): the same angle)."""
    if abs(vx) < limits.min_speed_for_steering:
        return 0.0
    delta = math.atan(wz * limits.wheelbase / vx)
    cap = limits.max_central_steering
    return max(-cap, min(cap, delta))


def ackermann_velocity(vx: float, wz: float, limits: LimoLimits) -> tuple[float, float]:
    """The (speed, yaw rate) an Ackermann chassis can drive for the command (vx, ωz).

    A curvature beyond the steering limit becomes the limit's (same speed, ω = vx·κ_max): the
    robot follows the tightest circle it can. Then the speed, yaw-rate and wheel-speed limits
    scale (vx, ω) by one λ, which keeps the radius. At |vx| below ``min_speed_for_steering``
    it cannot turn: ω = 0."""
    _, w = steerable(vx, wz, limits.max_curvature, limits.min_speed_for_steering)
    lam = _scale([(vx, limits.max_linear), (w, limits.max_angular),
                  (abs(vx) + abs(w) * limits.track / 2, limits.max_wheel_speed)])
    return lam * vx, lam * w


def ackermann_field(v: float, w: float, limits: LimoLimits) -> float:
    """The ``0x111`` steering field for a drivable (speed, yaw rate): central angle → inner angle
    (clamped to the inner limit, which only rounding can reach) → / 1.64 (``ackermann``)."""
    if abs(v) < limits.min_speed_for_steering:
        return 0.0
    central = math.atan(w * limits.wheelbase / v)
    inner = ackermann.central_to_inner(central, limits.wheelbase, limits.track)
    inner = max(-limits.max_steering, min(limits.max_steering, inner))
    # Towards zero on the wire's 0.001 grid, as AgileX's int16 cast does (limo_driver.cpp
    # ``setMotionCommand``): the chassis is never asked for more than the inner wheel's limit.
    return math.trunc(ackermann.steering_field(inner) * 1e3) / 1e3


def command_to_motion(vx: float, vy: float, wz: float, mode: MotionMode, limits: LimoLimits) -> MotionCommand:
    """The motion frame executing body velocity (vx, vy, ωz) in ``mode``, within ``limits``.

    Non-finite input yields a stop frame: a bridge must never forward NaN to motors."""
    if not all(math.isfinite(c) for c in (vx, vy, wz)):
        return MotionCommand()
    r = limits.track / 2
    if mode == MotionMode.DIFFERENTIAL:
        lam = _scale([(vx, limits.max_linear), (wz, limits.max_angular),
                      (abs(vx) + abs(wz) * r, limits.max_wheel_speed)])
        return MotionCommand(linear=lam * vx, angular=lam * wz)
    if mode == MotionMode.MECANUM:
        r += limits.wheelbase / 2
        lam = _scale([(vx, limits.max_linear), (vy, limits.max_lateral), (wz, limits.max_angular),
                      (abs(vx) + abs(vy) + abs(wz) * r, limits.max_wheel_speed)])
        return MotionCommand(linear=lam * vx, angular=lam * wz, lateral=lam * vy)
    v, w = ackermann_velocity(vx, wz, limits)
    # The angular field stays 0, as AgileX's driver sends it: in Ackermann mode the chassis
    # steers by the steering field alone (limo_driver.cpp ``twistCmdCallback``).
    return MotionCommand(linear=v, steering=ackermann_field(v, w, limits))


class WheelOdometry:
    """Planar dead reckoning from cumulative wheel travel, optionally with IMU yaw.

    ``max_step`` rejects a jump no real robot makes between two 0x311 frames (a reset
    counter, or garbage that passed the 8-bit checksum): the reference is re-taken without
    moving the pose, and ``jumps`` counts it.
    """

    def __init__(self, track: float, max_step: float = 0.5):
        self.track = track
        self.max_step = max_step
        self.x = 0.0
        self.y = 0.0
        self.yaw = 0.0
        self.jumps = 0
        self._last: tuple[float, float] | None = None
        self._imu_offset: float | None = None
        self._imu_yaw: float | None = None

    def reset_reference(self) -> None:
        """After a reconnect the counters may have restarted: take the next frame as reference."""
        self._last = None

    def update_imu_yaw(self, yaw: float) -> None:
        if self._imu_offset is None:
            self._imu_offset = yaw - self.yaw  # continue from the current heading
        self._imu_yaw = wrap_angle(yaw - self._imu_offset)
        self.yaw = self._imu_yaw

    def update_wheels(self, left: float, right: float, lateral_step: float = 0.0) -> bool:
        """Integrate one odometry frame; ``lateral_step`` (m, body y) is mecanum side travel
        the wheel counters cannot see. False when the frame was only taken as reference."""
        if self._last is None:
            self._last = (left, right)
            return False
        dl, dr = left - self._last[0], right - self._last[1]
        self._last = (left, right)
        if abs(dl) > self.max_step or abs(dr) > self.max_step:
            self.jumps += 1
            return False
        ds = 0.5 * (dl + dr)
        if self._imu_yaw is None:
            dyaw = (dr - dl) / self.track
            mid = self.yaw + 0.5 * dyaw
            self.yaw = wrap_angle(self.yaw + dyaw)
        else:
            mid = self.yaw  # IMU heading is absolute; the step uses the latest one
        c, s = math.cos(mid), math.sin(mid)
        self.x += ds * c - lateral_step * s
        self.y += ds * s + lateral_step * c
        return True
