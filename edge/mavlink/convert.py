"""Frame conventions between riskfield and MAVLink autopilots (pure maths; the rotations are
``riskfield.services.geometry.transforms``: MAVLink ATTITUDE angles are intrinsic Z-Y-X Euler
angles, ``euler_zyx_matrix``).

riskfield
    **map frame = ENU**: x east, y north, z up, with its origin at the autopilot's local
    (EKF) origin. **Body frame = FLU**: x forward, y left, z up. Commands are body FLU
    velocities and a yaw rate about +z (counter-clockwise seen from above).
MAVLink (PX4, ArduPilot)
    local frame **NED** (x north, y east, z down), body frame **FRD** (x forward, y right,
    z down); yaw is clockwise from north.

Conversions (P swaps NED↔ENU, F flips FLU↔FRD; both are their own inverse)::

    P = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]     (x, y, z)_ENU = (y, x, −z)_NED
    F = diag(1, −1, −1)                         (x, y, z)_FRD = (x, −y, −z)_FLU
    R_ENU←FLU = P · R_NED←FRD · F               (attitude)
    ω_FRD = F · ω_FLU                           (so yaw rate_FRD = −ωz_FLU)

A level vehicle facing north has NED yaw 0 and ENU yaw +π/2: yaw_ENU = π/2 − yaw_NED.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from riskfield.protocol.platforms import MULTICOPTER
from riskfield.services.geometry.transforms import euler_zyx_matrix, matrix_to_quat

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]

MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_NED = 8
#: SET_POSITION_TARGET_LOCAL_NED.type_mask: use vx, vy, vz and yaw rate; ignore position,
#: acceleration and yaw (bits 0-2, 6-8, 10 set; bit 11 clear).
VELOCITY_YAWRATE_MASK = 0x5C7

P = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
F = np.diag([1.0, -1.0, -1.0])


def ned_to_enu(v: tuple[float, float, float] | np.ndarray) -> tuple[float, float, float]:
    return float(v[1]), float(v[0]), -float(v[2])


def attitude_ned_frd_to_enu_flu(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R_ENU←FLU from an ATTITUDE message's roll, pitch, yaw (rad)."""
    return P @ euler_zyx_matrix(roll, pitch, yaw) @ F


class VelocityLimits(BaseModel):
    """Bounds of the setpoint; exceeded → the whole command is scaled by one factor (see below).
    Defaults from the platform description ``protocol.platforms.MULTICOPTER``."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    max_horizontal: Pos = Field(default=MULTICOPTER.max_speed, description="|horizontal velocity| (m/s)")
    max_vertical: Pos = Field(default=MULTICOPTER.max_vertical, description="|vertical velocity| (m/s)")
    max_yaw_rate: Pos = Field(default=MULTICOPTER.max_yaw_rate, description="|yaw rate| (rad/s)")


@dataclass(frozen=True)
class Setpoint:
    """Fields of SET_POSITION_TARGET_LOCAL_NED for a velocity + yaw-rate setpoint."""

    vx: float
    vy: float
    vz: float
    yaw_rate: float
    frame: int = MAV_FRAME_BODY_NED
    type_mask: int = VELOCITY_YAWRATE_MASK

    @property
    def is_zero(self) -> bool:
        return self.vx == 0.0 and self.vy == 0.0 and self.vz == 0.0 and self.yaw_rate == 0.0


def limit(linear: tuple[float, float, float], wz: float, limits: VelocityLimits) -> tuple[np.ndarray, float]:
    """Scale (v, ωz) by one λ ∈ [0, 1] into the limits: the direction of a filtered command is
    kept, and λ·u stays inside an affine barrier constraint that u and 0 satisfy."""
    v = np.asarray(linear, dtype=float)
    if not (np.isfinite(v).all() and math.isfinite(wz)):
        return np.zeros(3), 0.0
    lam = 1.0
    for value, bound in ((math.hypot(v[0], v[1]), limits.max_horizontal), (abs(v[2]), limits.max_vertical),
                         (abs(wz), limits.max_yaw_rate)):
        if value > bound:
            lam = min(lam, bound / value)
    return lam * v, lam * wz


def command_to_setpoint(linear: tuple[float, float, float], wz: float, limits: VelocityLimits,
                        frame: int = MAV_FRAME_BODY_NED, r_ned_frd: np.ndarray | None = None) -> Setpoint:
    """Body FLU velocity and yaw rate → a setpoint in ``frame``.

    ``MAV_FRAME_BODY_NED`` (8): the velocity is in the body frame (FRD) — no attitude needed.
    ``MAV_FRAME_LOCAL_NED`` (1): rotated into NED with the vehicle's attitude ``r_ned_frd``;
    without one the setpoint is zero (a velocity in an unknown direction is not sent)."""
    v_flu, w = limit(linear, wz, limits)
    v_frd = F @ v_flu
    if frame == MAV_FRAME_BODY_NED:
        v = v_frd
    elif frame == MAV_FRAME_LOCAL_NED:
        if r_ned_frd is None:
            return Setpoint(0.0, 0.0, 0.0, 0.0, frame)
        v = r_ned_frd @ v_frd
    else:
        raise ValueError(f"unsupported MAV_FRAME {frame}; use 1 (LOCAL_NED) or 8 (BODY_NED)")
    return Setpoint(float(v[0]), float(v[1]), float(v[2]), -float(w), frame)


@dataclass(frozen=True)
class PoseENU:
    """A RobotState's content: ENU position and velocity, ENU←FLU attitude, world angular velocity."""

    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    linear_velocity: tuple[float, float, float]
    angular_velocity: tuple[float, float, float]


def vehicle_state(local_position: tuple[float, ...], velocity_ned: tuple[float, ...],
                  attitude: tuple[float, float, float], rates_frd: tuple[float, float, float]) -> PoseENU:
    """LOCAL_POSITION_NED (x, y, z, vx, vy, vz) + ATTITUDE (roll, pitch, yaw, rates) → ENU state.

    Angular velocity is given in the world (ENU) frame: ω_ENU = R_ENU←FLU · F · ω_FRD."""
    r = attitude_ned_frd_to_enu_flu(*attitude)
    w = r @ (F @ np.asarray(rates_frd, dtype=float))
    return PoseENU(
        position=ned_to_enu(local_position),
        orientation=matrix_to_quat(r),
        linear_velocity=ned_to_enu(velocity_ned),
        angular_velocity=(float(w[0]), float(w[1]), float(w[2])),
    )
