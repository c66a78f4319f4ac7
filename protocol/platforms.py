"""Robot platforms: one home for a platform's dimensions and limits.

Everything that models a LIMO reads ``LIMO`` from here: the serial bridge's command limits
(``edge/limo/kinematics.LimoLimits``), the chassis emulator (``edge/limo/emulator``), the
simulator's LIMO models (``services/simulator/robots``) and the safety filter's unicycle (its
footprint and input bounds, ``services/safety_filter/config``). It
lives in the wire-contract package because both ``edge/`` and ``services/`` may import it, and an
external client modelling the robot can too (pydantic only).

Sources, and which value won where the copies disagreed:

* body 0.322 × 0.220 m: the safety filter's footprint so far. Trossen's copy of the LIMO
  documentation (``TrossenRobotics/agilex_limo_docs``, ``specifications/limo.rst``) lists
  322 × 215 × 247 mm; the wider figure stays, the conservative one for a barrier.
* wheelbase 0.2 m, track 0.172 m, inner-wheel steering ±0.488 rad (central ~0.408 rad, minimum
  turning radius ~0.46 m; AgileX's pylimo has 0.48869), about 1 m/s no-load:
  ``shared/reference/hardware_and_zenoh.md``. (AgileX's ROS driver, ``agilexrobotics/
  limo_ros`` ``limo_base/include/limo_base/limo_params.h``, has track 0.176 m and a 1.5 m/s
  ``max_linear_speed`` that its ``limo_driver.cpp`` never applies; the reference's figures stay.)
* yaw rate 2.0 rad/s: no datasheet gives one (the chassis itself only bounds wheel speed, so
  differential ω could reach 2·1.0/0.172 ≈ 11.6 rad/s). The bridge's 2.0 wins over the
  simulator's 2.5: it is what the real robot obeys, and the filter plans with 2.0 too.
* acceleration 1.5 m/s², yaw acceleration 6 rad/s²: no datasheet figure either; the simulator's
  gentle first-order actuator for a 4.2 kg robot. A real unit should be measured. The filter's
  unicycle assumed 3.0 m/s² of deceleration; it now plans with these 1.5 (its gain cap 2 a / v
  halves, still above every default risk group's gain).
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class PlanarPlatform(BaseModel):
    """A wheeled ground robot: body rectangle, wheel geometry and motion limits (SI units)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
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


#: The AgileX LIMO (see the module docstring for where each figure comes from).
LIMO = PlanarPlatform(
    name="limo", length=0.322, width=0.220, wheelbase=0.2, track=0.172,
    max_linear=1.0, max_lateral=1.0, max_angular=2.0, max_wheel_speed=1.0, max_steering=0.488,
    max_accel=1.5, max_yaw_accel=6.0,
)
