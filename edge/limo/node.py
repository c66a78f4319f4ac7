"""``riskfield run limo``: the AgileX LIMO serial bridge.

Subscribes ``cmd/safe`` and writes a motion frame per command at once (no rate limiting: the
filter's rate is the robot's rate). A timer every ``poll_s`` reads the serial line, publishes
``state`` on each odometry step, runs the watchdog and reopens a lost port. Diagnostics go
to ``{prefix}/{robot}/limo/diagnostics`` every ``diagnostics_period_s``.

A second watchdog with the same ``watchdog_s`` runs on a thread of its own
(``watchdog.CommandWatchdog``) and writes the stop frame if the loop cannot (a handler or a
timer stuck); its counts are in the node's status (``watchdog_thread_stops``).

``dry_run=true`` (first bring-up) keeps the real port and its feedback but writes stop frames only;
each withheld command is logged (rate-limited) and counted in the status (``withheld_commands``).
"""

from __future__ import annotations

import logging
import time
from typing import ClassVar

from pydantic import Field
from pydantic_settings import SettingsConfigDict

from riskfield.protocol import RobotState, VelocityCommand
from riskfield.services.geometry.transforms import yaw_quaternion
from riskfield.services.runtime import Node, NodeSettings, ServiceSpec

from .bridge import BridgeConfig, LimoBridge, PlanarState
from .messages import LimoDiagnostics
from .serial_link import SerialLink
from .watchdog import CommandWatchdog


class LimoSettings(NodeSettings, BridgeConfig):
    """The bridge core's ``BridgeConfig`` (flat: ``--set watchdog_s=0.3``, ``RISKFIELD_MAX_LINEAR``)
    plus the serial line and the node's timers."""

    model_config = SettingsConfigDict(populate_by_name=True)
    SERVICE: ClassVar[str] = "limo"

    port: str = Field(default="/dev/ttyTHS1", validation_alias="riskfield_limo_port",
                      description="serial device (env RISKFIELD_LIMO_PORT)")
    baudrate: int = Field(default=460800, gt=0)
    """Serial speed of the LIMO's chassis link."""
    poll_s: float = Field(default=0.005, gt=0, description="serial read, state, watchdog and reopen period")
    reconnect_s: float = Field(default=0.5, gt=0, description="a lost port is reopened this often")
    diagnostics_period_s: float = Field(default=0.5, gt=0)
    """Period of limo/diagnostics (battery, errors, link counters)."""
    state_frame: str = "map"
    """frame_id of the chassis odometry published as state."""
    publish_state: bool = Field(default=True, description=(
        "publish the chassis odometry as `state`; false where another source is the robot's state "
        "(a simulator moved by the same `cmd/safe`, deploy/compose.limo-emulator.yml): one source only"))


def to_robot_state(s: PlanarState, frame_id: str) -> RobotState:
    """A planar estimate as a ``RobotState``: z = 0, yaw-only quaternion, world-frame velocity."""
    vx, vy = s.world_velocity()
    msg = RobotState(position=(s.x, s.y, 0.0), orientation=tuple(yaw_quaternion(s.yaw).tolist()),
                     linear_velocity=(vx, vy, 0.0), angular_velocity=(0.0, 0.0, s.wz))
    msg.header.frame_id = frame_id
    return msg


class LimoNode:
    def __init__(self, node: Node, s: LimoSettings):
        self.node, self.s = node, s
        self.core = LimoBridge(s)  # the settings are a BridgeConfig
        self.link = SerialLink(s.port, s.baudrate, s.reconnect_s)
        self.diag_key = node.keys.key("limo/diagnostics")
        self.watchdog = CommandWatchdog(s.watchdog_s, s.stop_repeat_s).start()
        node.subscribe(node.keys.cmd_safe, VelocityCommand, self.on_command)
        node.every(s.poll_s, self.poll)
        node.every(s.diagnostics_period_s, self.publish_diagnostics)
        if s.dry_run:
            node.log.warning("dry run: %s is driven with stop frames only; cmd/safe is counted, not executed", s.port)
        self.poll()

    def _write(self, data: bytes) -> None:
        try:
            self.link.write(data)
        except ConnectionError as exc:
            self._lost(str(exc))

    def _lost(self, why: str) -> None:
        self.watchdog.detach()
        self.core.on_disconnected()
        self.node.ratelog(logging.ERROR, "link", f"LIMO serial link lost ({why}); reopening {self.s.port} "
                          f"every {self.s.reconnect_s} s")

    def on_command(self, cmd: VelocityCommand) -> None:
        now = time.monotonic()
        withheld = self.core.diag.withheld_commands
        frame = self.core.on_command(cmd.linear[0], cmd.linear[1], cmd.angular[2], now)
        if self.core.diag.withheld_commands > withheld:
            m = self.core.withheld
            assert m is not None
            self.node.ratelog(logging.WARNING, "dry-run", f"dry run: withheld cmd/safe linear={m.linear:.3f} "
                              f"lateral={m.lateral:.3f} angular={m.angular:.3f} steering={m.steering:.3f}, "
                              f"sent a stop ({self.core.diag.withheld_commands} withheld so far)")
        self.watchdog.commanded(not self.core.stopped, now)
        if self.link.is_open:
            self._write(frame)
        else:
            self.node.ratelog(logging.WARNING, "no-link", f"cmd/safe received but {self.s.port} is not open")

    def poll(self) -> None:
        now = time.monotonic()
        if self.link.try_open(now):
            self.node.log.info("opened %s at %d baud", self.s.port, self.s.baudrate)
            self.watchdog.attach(self.link.fileno())
            self._write(self.core.on_connected(now))
        elif not self.link.is_open:
            self.node.ratelog(logging.WARNING, "open", self.link.last_error or f"{self.s.port} is not open")
        if self.link.is_open:
            try:
                data = self.link.read()
            except ConnectionError as exc:
                self._lost(str(exc))
                data = b""
            if data and self.core.on_bytes(data, now) and self.s.publish_state:
                state = self.core.state(now)
                if state is not None:
                    self.node.publish(self.node.keys.state, to_robot_state(state, self.s.state_frame))
        if self.link.is_open:
            self._write(self.core.tick(now))
        if self.core.stopped:
            self.watchdog.settled()

    def publish_diagnostics(self) -> None:
        d = self.core.diagnostics(time.monotonic())
        self.node.publish(self.diag_key, LimoDiagnostics(
            port=self.s.port, connected=d.connected, battery_v=d.battery_v, error_bits=d.error_bits,
            vehicle_state=d.vehicle_state, control_mode=d.control_mode, motion_mode=d.motion_mode,
            command_mode_confirmed=d.command_mode_confirmed, mode_mismatch=d.mode_mismatch,
            frames_ok=d.frames_ok, frames_bad=d.frames_bad, bytes_skipped=d.bytes_skipped,
            reconnects=d.reconnects, watchdog_stops=d.watchdog_stops, commands=d.commands,
            odometry_jumps=d.odometry_jumps, feedback_age_ms=d.feedback_age_s * 1e3 if d.feedback_age_s >= 0 else -1.0,
        ))
        for name in ("frames_ok", "frames_bad", "bytes_skipped", "reconnects", "watchdog_stops", "commands",
                     "withheld_commands"):
            self.node.stats[name] = float(getattr(d, name))
        self.node.stats["connected"] = float(d.connected)
        self.node.stats["dry_run"] = float(self.s.dry_run)
        self.node.stats["watchdog_thread_stops"] = float(self.watchdog.fired)
        self.node.stats["watchdog_thread_write_errors"] = float(self.watchdog.write_errors)
        if d.error_bits:
            self.node.ratelog(logging.WARNING, "chassis-error", f"chassis reports error bits {d.error_bits:#06x}")
        if d.mode_mismatch:
            self.node.ratelog(logging.WARNING, "mode", f"chassis reports motion mode {d.motion_mode}, "
                              f"configured {self.s.motion_mode.name.lower() if self.s.motion_mode else 'auto'}")

    def close(self) -> None:
        """Stop the robot before letting go of the port."""
        if self.link.is_open:
            self._write(self.core.shutdown())
            time.sleep(0.01)  # let the stop frame leave the UART before the fd closes
        self.watchdog.stop()
        self.link.close()


def setup(node: Node, s: LimoSettings) -> LimoNode:
    return LimoNode(node, s)


SERVICE = ServiceSpec("limo", LimoSettings, setup)
