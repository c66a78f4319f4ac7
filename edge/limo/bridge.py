"""The LIMO bridge core: commands → motion frames, feedback bytes → planar state. No I/O.

The node calls it with the monotonic time and writes whatever bytes it returns to the
serial link. Rules it enforces:

* **Command mode.** On every (re)connection it sends ``0x421`` enable and a stop frame; it
  repeats the enable every ``enable_retry_s`` until the chassis reports control mode 1. Once
  confirmed it does not insist again on that connection: if the remote control takes over
  (control mode changes), the operator's takeover wins and is reported, not fought.
  ``motion_mode=mecanum`` sends the mecanum form of the frame (d2 = 1, AgileX's
  ``enableMcMode``) and, like AgileX's ``use_mcnamu``, drives mecanum whatever ``0x211`` d6 says:
  the chassis cannot see which wheels are mounted and may report 0 (differential).
* **Watchdog.** A command older than ``watchdog_s`` is replaced by a stop frame, repeated every
  ``stop_repeat_s`` while no command comes (a frame lost on the line cannot leave the robot
  moving). Shutdown returns a stop frame too.
* **Limits.** Every command is scaled into the platform limits (``kinematics.command_to_motion``).
* **Dry run.** ``dry_run`` keeps the link, the enable frame, the watchdog and the feedback as they
  are and replaces every motion frame that would move the chassis by a stop, counting it
  (``withheld_commands``): the first power-up on the real port and camera, wheels still.
* **State.** Wheel odometry dead reckoning (IMU yaw when present) and the measured velocities
  of the motion state frame (IMU yaw rate when fresh) give ``PlanarState``. In Ackermann mode
  the yaw rate comes from the steering feedback, as AgileX's ``publishOdometry`` computes it:
  the field scaled to the inner wheel's angle, converted to the central angle, ω = v·tan c / L.

The watchdog here runs on the node's loop; the node adds one on a thread of its own
(``watchdog.CommandWatchdog``) that stops the chassis even while that loop is stuck.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pydantic import Field, field_validator

from . import ackermann
from .kinematics import LimoLimits, MotionMode, Pos, WheelOdometry, command_to_motion
from .protocol import (
    ControlModeCommand,
    FrameParser,
    ImuAccel,
    ImuEuler,
    ImuGyro,
    MotionCommand,
    MotionState,
    Odometry,
    SystemState,
    decode,
    encode,
)

COMMAND_MODE = 1  # control mode reported by the chassis when it obeys the serial line


class BridgeConfig(LimoLimits):
    """The bridge core's parameters: the platform limits plus command mode, watchdog and feedback.
    ``motion_mode=None`` ("auto") follows the mode the chassis reports (differential until it does)."""

    motion_mode: MotionMode | None = Field(default=None, description=(
        "auto (follow the chassis), differential, ackermann or mecanum"))
    watchdog_s: Pos = Field(default=0.2, description="a command older than this is replaced by a stop frame")
    stop_repeat_s: Pos = Field(default=0.1, description="stop frames repeat this often while no command comes")
    enable_retry_s: Pos = Field(default=1.0, description="the serial-command-mode request repeats this often "
                                                          "until the chassis confirms it")
    feedback_timeout_s: Pos = Field(default=0.5, description="no feedback for this long: no state is published")
    use_imu: bool = Field(default=True, description="IMU yaw and yaw rate replace the wheels' when present")
    dry_run: bool = Field(default=False, description=(
        "bring-up: the real serial port and feedback, but every motion frame is a stop: each cmd/safe that "
        "would have moved the chassis is withheld, counted (status: withheld_commands) and logged"))

    @field_validator("motion_mode", mode="before")
    @classmethod
    def _parse_mode(cls, value: object) -> object:
        if value is None or (isinstance(value, str) and value.strip().lower() == "auto"):
            return None
        return MotionMode.parse(value) if isinstance(value, (str, int)) else value

    @property
    def limits(self) -> LimoLimits:
        return self


@dataclass(frozen=True)
class PlanarState:
    """Pose in the odometry frame (starts at the first odometry frame) and body velocities."""

    x: float
    y: float
    yaw: float
    vx: float  # body forward, m/s
    vy: float  # body left, m/s
    wz: float  # yaw rate, rad/s
    stamp: float  # monotonic time of the feedback it was made from
    steering: float = 0.0  # central (bicycle) steering angle, Ackermann, rad

    def world_velocity(self) -> tuple[float, float]:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.vx * c - self.vy * s, self.vx * s + self.vy * c


@dataclass
class Diagnostics:
    connected: bool = False
    reconnects: int = 0
    vehicle_state: int = -1
    control_mode: int = -1
    motion_mode: int = -1  # as reported by the chassis
    battery_v: float = 0.0
    error_bits: int = 0
    command_mode_confirmed: bool = False
    mode_mismatch: bool = False
    frames_ok: int = 0
    frames_bad: int = 0
    bytes_skipped: int = 0
    unknown_frames: int = 0
    odometry_jumps: int = 0
    commands: int = 0
    withheld_commands: int = 0  # dry run: commands that would have moved the chassis, sent as stops
    watchdog_stops: int = 0
    feedback_age_s: float = -1.0


class LimoBridge:
    def __init__(self, config: BridgeConfig | None = None):
        self.config = config or BridgeConfig()
        self.parser = FrameParser()
        self.odometry = WheelOdometry(self.config.limits.track)
        self.diag = Diagnostics()
        self.last_motion: MotionCommand | None = None  # what was last written
        self.withheld: MotionCommand | None = None  # dry run: the last motion frame not sent
        self._last_cmd_t: float | None = None
        self._stopped = True
        self._last_stop_t = -math.inf
        self._last_enable_t = -math.inf
        self._last_feedback_t: float | None = None
        self._motion: MotionState | None = None
        self._motion_t = -math.inf
        self._gyro_z: float | None = None
        self._gyro_t = -math.inf
        self._accel: ImuAccel | None = None
        self._state_t: float | None = None

    # -- link ---------------------------------------------------------------------------------
    @property
    def mode(self) -> MotionMode:
        if self.config.motion_mode is not None:
            return self.config.motion_mode
        try:
            return MotionMode(self.diag.motion_mode)
        except ValueError:
            return MotionMode.DIFFERENTIAL

    @property
    def stopped(self) -> bool:
        """True once the last motion frame written was a stop (a zero command, the watchdog, shutdown)."""
        return self._stopped

    def _enable_frame(self) -> bytes:
        return encode(ControlModeCommand(enable=True, mecanum=self.config.motion_mode == MotionMode.MECANUM))

    def on_connected(self, now: float) -> bytes:
        """Bytes to write right after the port opened: enable command mode, then stop."""
        if self.diag.connected:
            return b""
        self.diag.connected = True
        self.diag.command_mode_confirmed = False
        self.parser.reset()
        self.odometry.reset_reference()
        self._last_enable_t = now
        self._stopped = True
        self._last_stop_t = now
        self.last_motion = MotionCommand()
        return self._enable_frame() + encode(self.last_motion)

    def on_disconnected(self) -> None:
        if self.diag.connected:
            self.diag.connected = False
            self.diag.reconnects += 1
        self._last_feedback_t = None

    # -- commands -----------------------------------------------------------------------------
    def on_command(self, vx: float, vy: float, wz: float, now: float) -> bytes:
        """The motion frame for a new ``cmd/safe`` (scaled into the limits)."""
        self.diag.commands += 1
        self.last_motion = command_to_motion(vx, vy, wz, self.mode, self.config.limits)
        if self.config.dry_run and not self.last_motion.is_stop:
            self.diag.withheld_commands += 1
            self.withheld = self.last_motion
            self.last_motion = MotionCommand()
        self._last_cmd_t = now
        self._stopped = self.last_motion.is_stop
        if self._stopped:
            self._last_stop_t = now
        return encode(self.last_motion)

    def tick(self, now: float) -> bytes:
        """Periodic duties: watchdog stop (and its repeats), command-mode enable retries."""
        out = b""
        if not self.diag.connected:
            return out
        if not self.diag.command_mode_confirmed and now - self._last_enable_t >= self.config.enable_retry_s:
            self._last_enable_t = now
            out += self._enable_frame()
        stale = self._last_cmd_t is None or now - self._last_cmd_t > self.config.watchdog_s
        if stale and not self._stopped:
            self._stopped = True
            self.diag.watchdog_stops += 1
            self._last_stop_t = now
            self.last_motion = MotionCommand()
            out += encode(self.last_motion)
        elif self._stopped and now - self._last_stop_t >= self.config.stop_repeat_s:
            self._last_stop_t = now
            self.last_motion = MotionCommand()
            out += encode(self.last_motion)
        return out

    def shutdown(self) -> bytes:
        self._stopped = True
        self.last_motion = MotionCommand()
        return encode(self.last_motion)

    # -- feedback -----------------------------------------------------------------------------
    def on_bytes(self, data: bytes, now: float) -> bool:
        """Feed received bytes; True when a new odometry step moved the state estimate."""
        moved = False
        for frame in self.parser.feed(data):
            msg = decode(frame)
            if msg is None or isinstance(msg, (MotionCommand, ControlModeCommand)):
                self.diag.unknown_frames += 1  # our own commands echoed back, or ids we do not use
                continue
            self._last_feedback_t = now
            moved |= self._apply(msg, now)
        p, d = self.parser, self.diag
        d.frames_ok, d.frames_bad, d.bytes_skipped = p.frames_ok, p.frames_bad, p.bytes_skipped
        d.odometry_jumps = self.odometry.jumps
        return moved

    def _apply(self, msg: object, now: float) -> bool:
        d = self.diag
        if isinstance(msg, SystemState):
            d.vehicle_state, d.control_mode, d.motion_mode = msg.vehicle_state, msg.control_mode, msg.motion_mode
            d.battery_v, d.error_bits = msg.battery_v, msg.error_bits
            if msg.control_mode == COMMAND_MODE:
                d.command_mode_confirmed = True
            d.mode_mismatch = self._mismatch(msg.motion_mode)
        elif isinstance(msg, MotionState):
            self._motion, self._motion_t = msg, now
        elif isinstance(msg, ImuGyro):
            if self.config.use_imu:
                self._gyro_z, self._gyro_t = msg.z, now
        elif isinstance(msg, ImuEuler):
            if self.config.use_imu:
                self.odometry.update_imu_yaw(msg.yaw)
        elif isinstance(msg, ImuAccel):
            self._accel = msg
        elif isinstance(msg, Odometry):
            lateral = 0.0
            if self.mode == MotionMode.MECANUM and self._motion is not None and self._state_t is not None:
                lateral = self._motion.lateral * max(0.0, min(now - self._state_t, 0.1))
            moved = self.odometry.update_wheels(msg.left, msg.right, lateral)
            self._state_t = now
            return moved
        return False

    def _mismatch(self, reported: int) -> bool:
        forced = self.config.motion_mode
        if forced is None:
            return False
        if forced == MotionMode.MECANUM:
            # AgileX's driver ignores d6 under use_mcnamu (limo_driver.cpp ``parseFrame``,
            # MSG_SYSTEM_STATE_ID): mecanum wheels on a chassis reporting 0 is the normal case.
            # Only the Ackermann latch contradicts mecanum wheels.
            return reported == MotionMode.ACKERMANN
        return reported != int(forced)

    def feedback_fresh(self, now: float) -> bool:
        return self._last_feedback_t is not None and now - self._last_feedback_t <= self.config.feedback_timeout_s

    def state(self, now: float) -> PlanarState | None:
        """The current estimate; None before any odometry or when feedback has gone stale."""
        if self._state_t is None or not self.feedback_fresh(now):
            return None
        fresh = self.config.feedback_timeout_s
        m = self._motion if now - self._motion_t <= fresh else None
        vx, vy, wz = (m.linear, m.lateral, m.angular) if m is not None else (0.0, 0.0, 0.0)
        central = 0.0
        if m is not None and self.mode == MotionMode.ACKERMANN:
            central = self.central_steering(m.steering)
            # limo_driver.cpp ``publishOdometry`` (MODE_ACKERMANN): ω = ±v / r, r = L / tan|i| + T/2,
            # which is v·tan(c)/L. Its vx = v·cos c, vy = v·sin c are not followed: the wheel odometry
            # here is the rear axle's, which moves along the body's x only.
            vx, vy = m.linear, 0.0
            wz = m.linear * math.tan(central) / self.config.wheelbase
        if self._gyro_z is not None and now - self._gyro_t <= fresh:
            wz = self._gyro_z
        o = self.odometry
        return PlanarState(o.x, o.y, o.yaw, vx, vy, wz, self._state_t, central)

    def central_steering(self, feedback_field: float) -> float:
        """The central (bicycle) angle a ``0x221`` steering field reports: field → inner → central."""
        inner = ackermann.inner_from_feedback_field(feedback_field)
        return ackermann.inner_to_central(inner, self.config.wheelbase, self.config.track)

    def diagnostics(self, now: float) -> Diagnostics:
        self.diag.feedback_age_s = -1.0 if self._last_feedback_t is None else now - self._last_feedback_t
        return self.diag
