"""``riskfield run mavlink``: ``cmd/safe`` → PX4/ArduPilot velocity setpoints; vehicle → ``state``.

``url`` (env ``RISKFIELD_MAVLINK_URL``, default ``udpin:127.0.0.1:14550``) is a pymavlink
connection string. MAVLink 1/2 without signing authenticates nobody, and the vehicle state read here
is what the safety filter trusts, so the default listens on loopback only (an autopilot on a serial
port, or mavlink-router forwarding to it); a listener beyond loopback is announced at start.

The node polls the link every ``poll_s``, publishes ``RobotState`` in the
ENU map frame (see ``convert``) whenever a LOCAL_POSITION_NED or ATTITUDE arrives and both
are fresh, and sends what the core's schedule asks for. It never arms or switches modes.
"""

from __future__ import annotations

import logging
import time
from typing import ClassVar

from pydantic import Field
from pydantic_settings import SettingsConfigDict
from pymavlink import mavutil

from riskfield.protocol import RobotState, VelocityCommand
from riskfield.services.runtime import Node, NodeSettings, ServiceSpec
from riskfield.services.runtime.session import only_this_host

from .bridge import Heartbeat, MavlinkBridge, MavlinkConfig, RequestInterval, SetpointOut

MAV = mavutil.mavlink
log = logging.getLogger(__name__)


class MavlinkSettings(NodeSettings, MavlinkConfig):
    """The bridge core's ``MavlinkConfig`` (flat: ``--set max_yaw_rate=0.5``) plus the link."""

    model_config = SettingsConfigDict(populate_by_name=True)
    SERVICE: ClassVar[str] = "mavlink"

    url: str = Field(default="udpin:127.0.0.1:14550", validation_alias="riskfield_mavlink_url",
                     description="pymavlink connection string (env RISKFIELD_MAVLINK_URL)")
    baudrate: int = Field(default=115200, gt=0, description="for serial links")
    poll_s: float = Field(default=0.005, gt=0)
    """Period of reading the MAVLink link (and publishing the state it brings)."""
    source_system: int = Field(default=255, ge=1, le=255)
    """MAVLink system id this bridge sends as (255: a ground station)."""
    source_component: int = Field(default=MAV.MAV_COMP_ID_MISSIONPLANNER, ge=0, le=255)
    """MAVLink component id this bridge sends as."""


def exposed_listener(url: str, published_on: str | None = None) -> str | None:
    """The host:port a pymavlink ``udpin:``/``tcpin:`` listener (``udp:`` is udpin in pymavlink's
    mavutil.mavlink_connection) accepts datagrams on from other hosts, or None (loopback, a serial
    port, an outgoing link). In a container, ``published_on`` is the host address its port is
    published on, as for the Zenoh listeners (runtime.session.exposed)."""
    proto, _, rest = url.partition(":")
    if proto not in ("udpin", "udp", "tcpin") or ":" not in rest:
        return None
    return None if only_this_host(rest.rsplit(":", 1)[0], published_on) else rest


class MavlinkNode:
    def __init__(self, node: Node, s: MavlinkSettings):
        self.node, self.s = node, s
        if (where := exposed_listener(s.url, s.published_on)) is not None:
            log.warning("MAVLink listener on %s beyond loopback: any host that reaches it can send the "
                        "vehicle state the safety filter trusts (MAVLink is unauthenticated here); "
                        "prefer udpin:127.0.0.1:PORT behind mavlink-router or a serial link", where)
        self.core = MavlinkBridge(s, t0=time.monotonic())  # the settings are a MavlinkConfig
        try:
            # autoreconnect: a USB/serial autopilot link is reopened after it drops (UDP needs nothing).
            self.conn = mavutil.mavlink_connection(s.url, baud=s.baudrate, source_system=s.source_system,
                                                   source_component=s.source_component, autoreconnect=True)
        except OSError as exc:
            raise ConnectionError(f"cannot open the MAVLink link {s.url}: {exc}") from None
        self.bad_messages = 0
        node.subscribe(node.keys.cmd_safe, VelocityCommand, self.on_command)
        node.every(s.poll_s, self.poll)

    def on_command(self, cmd: VelocityCommand) -> None:
        out = self.core.on_command(cmd.linear, cmd.angular[2], time.monotonic())
        if out is not None:
            self._send([out])

    def poll(self) -> None:
        now = time.monotonic()
        publish = False
        for _ in range(200):  # bounded: a flood must not starve the loop
            try:
                msg = self.conn.recv_match(blocking=False)
            except (OSError, ValueError) as exc:
                self.node.ratelog(logging.ERROR, "recv", f"MAVLink receive failed: {exc}")
                break
            if msg is None:
                break
            publish |= self._handle(msg, now)
        if publish:
            st = self.core.state(now)
            if st is not None:
                self.node.publish(self.node.keys.state, RobotState(
                    position=st.position, orientation=st.orientation, linear_velocity=st.linear_velocity,
                    angular_velocity=st.angular_velocity))
        self._send(self.core.tick(now))
        c = self.core.counters
        self.node.stats.update(setpoints=c.setpoints, zero_setpoints=c.zero_setpoints, heartbeats=c.heartbeats,
                               vehicle_heartbeats=c.vehicle_heartbeats, watchdog_stops=c.watchdog_stops,
                               bad_messages=self.bad_messages, foreign_messages=c.foreign_messages)

    def _handle(self, msg: object, now: float) -> bool:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.bad_messages += 1
            self.node.ratelog(logging.WARNING, "bad", "undecodable MAVLink bytes received")
            return False
        system, component = msg.get_srcSystem(), msg.get_srcComponent()
        if not self.core.accepts(system, component):
            self.node.ratelog(logging.WARNING, "foreign",
                              f"dropped {kind} from system {system} component {component}: the vehicle is system "
                              f"{self.s.vehicle_system} component {self.s.vehicle_component}")
            return False
        if kind == "HEARTBEAT":
            had = self.core.target
            self.core.on_heartbeat(system, component, msg.type, msg.autopilot, now)
            if had is None and self.core.target is not None:
                self.node.log.info("vehicle found: system %d component %d autopilot %d", *self.core.target,
                                   msg.autopilot)
        elif kind == "LOCAL_POSITION_NED":
            self.core.on_local_position(msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, now)
            return True
        elif kind == "ATTITUDE":
            self.core.on_attitude(msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed, now)
            return True
        return False

    def _send(self, items: list) -> None:
        mav = self.conn.mav
        try:
            for item in items:
                if isinstance(item, Heartbeat):
                    mav.heartbeat_send(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0, MAV.MAV_STATE_ACTIVE)
                elif isinstance(item, SetpointOut):
                    sp = item.setpoint
                    mav.set_position_target_local_ned_send(
                        item.time_boot_ms, item.target_system, item.target_component, sp.frame, sp.type_mask,
                        0.0, 0.0, 0.0, sp.vx, sp.vy, sp.vz, 0.0, 0.0, 0.0, 0.0, sp.yaw_rate)
                elif isinstance(item, RequestInterval):
                    mav.command_long_send(item.target_system, item.target_component,
                                          MAV.MAV_CMD_SET_MESSAGE_INTERVAL, 0, item.message_id, item.interval_us,
                                          0, 0, 0, 0, 0)
        except OSError as exc:  # e.g. the network went away: keep serving, try again next tick
            self.node.ratelog(logging.ERROR, "send", f"MAVLink send failed: {exc}")

    def close(self) -> None:
        """Leave the vehicle with a zero setpoint rather than the last velocity."""
        out = self.core.shutdown(time.monotonic())
        if out is not None:
            self._send([out])
        self.conn.close()


def setup(node: Node, s: MavlinkSettings) -> MavlinkNode:
    return MavlinkNode(node, s)


SERVICE = ServiceSpec("mavlink", MavlinkSettings, setup)
