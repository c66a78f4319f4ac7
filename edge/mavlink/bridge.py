"""The MAVLink bridge core: what to send when, and vehicle messages → state. No I/O, no pymavlink.

Schedule (``tick``):

* a GCS ``HEARTBEAT`` every 1/``heartbeat_hz`` s (1 Hz);
* a velocity + yaw-rate setpoint every 1/``setpoint_hz`` s (≥ 10 Hz; PX4 leaves OFFBOARD below
  2 Hz) — the last ``cmd/safe`` while it is fresh, **zero** once it is older than ``watchdog_s``
  (so a silent filter stops the vehicle instead of leaving it on its last velocity); a new
  ``cmd/safe`` is also sent at once (``on_command``);
* ``MAV_CMD_SET_MESSAGE_INTERVAL`` for LOCAL_POSITION_NED and ATTITUDE at ``stream_hz`` once the
  vehicle is seen, repeated every ``interval_retry_s`` while they do not stream.

The bridge never arms the vehicle or changes its mode: that stays the pilot's decision.
Only the configured vehicle is listened to (``vehicle_system`` / ``vehicle_component``, the
MAVLink header's source ids): messages from any other system or component on the link (a second
vehicle, a camera, another ground station, a forged sender) are dropped and counted
(``foreign_messages``). Setpoints are addressed to the configured vehicle once its autopilot
heartbeat is seen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from pydantic import Field

from riskfield.services.geometry.transforms import euler_zyx_matrix

from .convert import (
    MAV_FRAME_BODY_NED,
    MAV_FRAME_LOCAL_NED,
    Pos,
    PoseENU,
    Setpoint,
    VelocityLimits,
    command_to_setpoint,
    vehicle_state,
)

MAV_TYPE_GCS = 6
MAV_AUTOPILOT_INVALID = 8
MSG_ID_ATTITUDE = 30
MSG_ID_LOCAL_POSITION_NED = 32


@dataclass(frozen=True)
class Heartbeat:
    pass


@dataclass(frozen=True)
class SetpointOut:
    setpoint: Setpoint
    time_boot_ms: int
    target_system: int
    target_component: int


@dataclass(frozen=True)
class RequestInterval:
    message_id: int
    interval_us: int
    target_system: int
    target_component: int


Outgoing = Heartbeat | SetpointOut | RequestInterval


class MavlinkConfig(VelocityLimits):
    """The bridge core's parameters: the setpoint limits plus its schedule."""

    setpoint_hz: float = Field(default=20.0, ge=10, allow_inf_nan=False, description=(
        "setpoints per second while the vehicle is seen; below 10 autopilots drop out of offboard/guided "
        "control (PX4 below 2 Hz)"))
    heartbeat_hz: Pos = Field(default=1.0, description="GCS heartbeats per second")
    watchdog_s: Pos = Field(default=0.2, description="a cmd/safe older than this is replaced by zero setpoints")
    frame: Literal["body", "local"] = Field(default="body", description=(
        "setpoint frame: body (MAV_FRAME_BODY_NED, no attitude needed) or local (MAV_FRAME_LOCAL_NED)"))
    stream_hz: Pos = Field(default=30.0, description="LOCAL_POSITION_NED and ATTITUDE rate asked of the vehicle")
    interval_retry_s: Pos = Field(default=5.0, description="the stream request repeats this often until they come")
    state_timeout_s: Pos = Field(default=0.5, description="position and attitude older than this give no state")
    # 1/1: PX4's MAV_SYS_ID and MAV_COMP_ID defaults (src/modules/mavlink/mavlink_params.c) and
    # ArduPilot's SYSID_THISMAV with the compid GCS::init sets, MAV_COMP_ID_AUTOPILOT1
    # (libraries/GCS_MAVLink/GCS_Common.cpp).
    vehicle_system: int = Field(default=1, ge=1, le=255, description=(
        "MAVLink system id of the vehicle (PX4 MAV_SYS_ID, ArduPilot SYSID_THISMAV): messages from another "
        "system are dropped and counted (foreign_messages)"))
    vehicle_component: int = Field(default=1, ge=0, le=255, description=(
        "MAVLink component id of its autopilot (1 = MAV_COMP_ID_AUTOPILOT1): messages from other components "
        "are dropped and counted (foreign_messages)"))

    @property
    def limits(self) -> VelocityLimits:
        return self

    @property
    def mav_frame(self) -> int:
        return MAV_FRAME_BODY_NED if self.frame == "body" else MAV_FRAME_LOCAL_NED


@dataclass
class Counters:
    setpoints: int = 0
    zero_setpoints: int = 0
    heartbeats: int = 0
    vehicle_heartbeats: int = 0
    commands: int = 0
    watchdog_stops: int = 0
    interval_requests: int = 0
    foreign_messages: int = 0


class MavlinkBridge:
    def __init__(self, config: MavlinkConfig | None = None, t0: float = 0.0):
        self.config = config or MavlinkConfig()
        self.t0 = t0
        self.counters = Counters()
        self.target: tuple[int, int] | None = None
        self.autopilot = -1
        self._cmd: tuple[tuple[float, float, float], float] | None = None
        self._cmd_t = -math.inf
        self._stale = True
        self._last_hb = -math.inf
        self._last_sp = -math.inf
        self._last_req = -math.inf
        self._pos: tuple[tuple[float, ...], tuple[float, ...], float] | None = None  # (xyz, v, t)
        self._att: tuple[tuple[float, float, float], tuple[float, float, float], float] | None = None

    # -- vehicle → bridge ---------------------------------------------------------------------
    def accepts(self, system: int, component: int) -> bool:
        """Whether a message with these source ids comes from the configured vehicle (else counted)."""
        if (system, component) == (self.config.vehicle_system, self.config.vehicle_component):
            return True
        self.counters.foreign_messages += 1
        return False

    def on_heartbeat(self, system: int, component: int, mav_type: int, autopilot: int, now: float) -> None:
        if mav_type == MAV_TYPE_GCS or autopilot == MAV_AUTOPILOT_INVALID:
            return  # another ground station, not a vehicle
        self.counters.vehicle_heartbeats += 1
        if self.target is None:
            self.target = (system, component)
            self.autopilot = autopilot

    def on_local_position(self, x: float, y: float, z: float, vx: float, vy: float, vz: float, now: float) -> None:
        values = (x, y, z, vx, vy, vz)
        if all(math.isfinite(v) for v in values):
            self._pos = ((x, y, z), (vx, vy, vz), now)

    def on_attitude(self, roll: float, pitch: float, yaw: float, rollspeed: float, pitchspeed: float,
                    yawspeed: float, now: float) -> None:
        values = (roll, pitch, yaw, rollspeed, pitchspeed, yawspeed)
        if all(math.isfinite(v) for v in values):
            self._att = ((roll, pitch, yaw), (rollspeed, pitchspeed, yawspeed), now)

    def state(self, now: float) -> PoseENU | None:
        """The vehicle's ENU state once both streams are present and fresh."""
        if self._pos is None or self._att is None:
            return None
        timeout = self.config.state_timeout_s
        if now - self._pos[2] > timeout or now - self._att[2] > timeout:
            return None
        return vehicle_state(self._pos[0], self._pos[1], self._att[0], self._att[1])

    # -- riskfield → bridge -------------------------------------------------------------------
    def on_command(self, linear: tuple[float, float, float], wz: float, now: float) -> SetpointOut | None:
        self.counters.commands += 1
        self._cmd, self._cmd_t, self._stale = (linear, wz), now, False
        return self._setpoint(now)

    def _setpoint(self, now: float) -> SetpointOut | None:
        if self.target is None:
            return None
        fresh = self._cmd is not None and now - self._cmd_t <= self.config.watchdog_s
        if not fresh and not self._stale:
            self._stale = True
            self.counters.watchdog_stops += 1
        r = None if self._att is None else euler_zyx_matrix(*self._att[0])
        linear, wz = self._cmd if fresh and self._cmd is not None else ((0.0, 0.0, 0.0), 0.0)
        sp = command_to_setpoint(linear, wz, self.config.limits, self.config.mav_frame, r)
        self._last_sp = now
        self.counters.setpoints += 1
        self.counters.zero_setpoints += sp.is_zero
        ms = int(max(0.0, now - self.t0) * 1000) & 0xFFFFFFFF
        return SetpointOut(sp, ms, *self.target)

    def shutdown(self, now: float) -> SetpointOut | None:
        """A zero setpoint to leave the vehicle with (None before a vehicle was seen)."""
        self._cmd = None
        return self._setpoint(now)

    def tick(self, now: float) -> list[Outgoing]:
        out: list[Outgoing] = []
        if now - self._last_hb >= 1.0 / self.config.heartbeat_hz:
            self._last_hb = now
            self.counters.heartbeats += 1
            out.append(Heartbeat())
        if now - self._last_sp >= 1.0 / self.config.setpoint_hz:
            sp = self._setpoint(now)
            if sp is not None:
                out.append(sp)
        if self.target is not None and now - self._last_req >= self.config.interval_retry_s:
            # Always once (default stream rates may be a few Hz), then again while nothing streams.
            if self._last_req == -math.inf or self.state(now) is None:
                self._last_req = now
                interval = int(1e6 / self.config.stream_hz)
                for msg_id in (MSG_ID_LOCAL_POSITION_NED, MSG_ID_ATTITUDE):
                    out.append(RequestInterval(msg_id, interval, *self.target))
                    self.counters.interval_requests += 1
        return out
