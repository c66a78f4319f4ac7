"""ROS 2 bridge node: ``cmd/safe`` → CDR Twist on ``{ns}/cmd_vel``; CDR Odometry on
``{ns}/odom`` → ``state``. With zenoh-bridge-ros2dds in front of a stock ROS 2 driver
(``zenoh-bridge-ros2dds -n /<ns>``), the robot is driven by the safety filter's output.
When ``cmd/safe`` stops, zero Twists are streamed so the driver stops too."""

from __future__ import annotations

import logging
import time
from typing import ClassVar

from pydantic import Field

from riskfield.protocol import VelocityCommand

from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .messages import decode_odometry, encode_twist, odometry_to_state

CDR_ENCODING = "application/cdr"


class Ros2BridgeSettings(NodeSettings):
    SERVICE: ClassVar[str] = "ros2-bridge"

    namespace: str = ""  # ROS namespace as zenoh-bridge-ros2dds maps it, e.g. "limo1"
    cmd_vel_topic: str = "cmd_vel"
    odom_topic: str = "odom"
    watchdog_s: float = Field(default=0.2, gt=0)
    zero_rate_hz: float = Field(default=10.0, gt=0)


def ros_key(namespace: str, topic: str) -> str:
    return "/".join(p.strip("/") for p in (namespace, topic) if p.strip("/"))


class Ros2Bridge:
    """Core of the bridge: the watchdog that turns a silent ``cmd/safe`` into zero Twists."""

    def __init__(self, watchdog_s: float):
        self.watchdog_s = watchdog_s
        self.last_cmd = -float("inf")

    def on_cmd(self, cmd: VelocityCommand, now: float) -> bytes:
        self.last_cmd = now
        return encode_twist(cmd)

    def on_tick(self, now: float) -> bytes | None:
        if now - self.last_cmd > self.watchdog_s:
            return encode_twist(VelocityCommand.zero("ros2-bridge watchdog"))
        return None


def setup(node: Node, s: Ros2BridgeSettings) -> None:
    core = Ros2Bridge(s.watchdog_s)
    cmd_vel = ros_key(s.namespace, s.cmd_vel_topic)

    def on_safe(cmd: VelocityCommand) -> None:
        node.publish_raw(cmd_vel, core.on_cmd(cmd, time.monotonic()), CDR_ENCODING)

    def on_odom(key: str, payload: bytes) -> None:
        try:
            state = odometry_to_state(decode_odometry(payload))
        except ValueError as exc:
            node.ratelog(logging.WARNING, "odom", f"rejected an Odometry on {key}: {exc}")
            node.stats["odom_invalid"] = node.stats.get("odom_invalid", 0) + 1
            return
        node.publish(node.keys.state, state)

    def tick() -> None:
        zero = core.on_tick(time.monotonic())
        if zero is not None:
            node.publish_raw(cmd_vel, zero, CDR_ENCODING)

    node.subscribe(node.keys.cmd_safe, VelocityCommand, on_safe)
    node.subscribe(ros_key(s.namespace, s.odom_topic), None, on_odom)
    node.every(1.0 / s.zero_rate_hz, tick)


SERVICE = ServiceSpec("ros2-bridge", Ros2BridgeSettings, setup)
