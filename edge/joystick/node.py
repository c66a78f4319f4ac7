"""``riskfield run joystick``: Logitech Extreme 3D Pro (or any evdev joystick) → ``cmd/ref``.

``source``: ``evdev`` (default: the first Extreme 3D Pro, or ``device`` / ``RISKFIELD_JOYSTICK_DEVICE``),
``raw`` (``struct input_event`` records read from ``device``: a device node, FIFO or capture),
or ``recorded`` (a JSON recording at ``device``, see ``source.load_recording``).
A source with a descriptor (evdev, a FIFO or device node) wakes the loop as soon as events
wait (``waker.FdWaker``); others are polled every ``poll_s``, which also drives reconnection
and the fixed-rate publishing. A changed command is published at once, and the current one
(zero without dead-man or device) every 1/``rate_hz``.
"""

from __future__ import annotations

import logging
import time
import uuid
from typing import ClassVar, Literal

import zenoh
from pydantic import Field, field_validator
from pydantic_settings import SettingsConfigDict

from riskfield.protocol import VelocityCommand
from riskfield.services.runtime import Node, NodeSettings, ServiceSpec

from .gateway import GatewayConfig, JoystickGateway
from .mapping import AxisSpec, JoystickMapping, parse_code
from .source import DeviceLost, DeviceUnavailable, EvdevSource, EventSource, RawEventSource, load_recording
from .waker import FdWaker

#: The explicit ``deadman`` value of a joystick without a dead-man button.
NO_DEADMAN = "none"


class JoystickSettings(NodeSettings, GatewayConfig):
    model_config = SettingsConfigDict(populate_by_name=True)
    SERVICE: ClassVar[str] = "joystick"

    source: Literal["evdev", "raw", "recorded"] = "evdev"
    """evdev: a joystick device; raw: input_event records from device; recorded: a JSON recording at device."""
    device: str | None = Field(default=None, validation_alias="riskfield_joystick_device",
                               description="evdev path (env RISKFIELD_JOYSTICK_DEVICE), raw path, or recording")
    linear_x: str = "-ABS_Y"
    """Axis of the forward speed, e.g. -ABS_Y (a leading - inverts it; empty: unused)."""
    linear_y: str = ""
    """Axis of the lateral speed (mecanum), e.g. -ABS_X; empty: unused."""
    angular_z: str = "-ABS_RZ"
    """Axis of the yaw rate, e.g. -ABS_RZ (the stick's twist)."""
    speed_scale: str = "-ABS_THROTTLE"
    """Axis that scales every speed from min_scale to 1 (the throttle slider); empty: always 1."""
    deadman: str = Field(default="BTN_TRIGGER", description=(
        "the dead-man button (an input code name or number): released, the command is zero. "
        f"'{NO_DEADMAN}' drives without one (a bench or a simulator, never a robot near people)"))
    deadzone: float = Field(default=0.08, ge=0, lt=1)
    """Fraction of each axis' half-range around the centre that reads as zero."""
    max_linear: float = Field(default=0.5, gt=0)
    """Forward speed (m/s) at full stick."""
    max_lateral: float = Field(default=0.5, gt=0)
    """Lateral speed (m/s) at full stick (mecanum)."""
    max_angular: float = Field(default=1.0, gt=0)
    """Yaw rate (rad/s) at full twist."""
    min_scale: float = Field(default=0.0, ge=0, le=1)
    """Speed scale at the slider's low end."""
    poll_s: float = Field(default=0.01, gt=0)
    """Polling period of a source without a descriptor; also drives reconnection."""
    wake_on_input: bool = Field(default=True, description="wake on a readable device instead of waiting for poll_s")
    source_name: str = "joystick"
    """The source name its commands carry (VelocityCommand.source)."""

    def mapping(self) -> JoystickMapping:
        return JoystickMapping(
            linear_x=AxisSpec.parse(self.linear_x, self.deadzone),
            linear_y=AxisSpec.parse(self.linear_y, self.deadzone),
            angular_z=AxisSpec.parse(self.angular_z, self.deadzone),
            speed_scale=AxisSpec.parse(self.speed_scale, 0.0),
            deadman=None if self.deadman == NO_DEADMAN else parse_code(self.deadman),
            max_linear=self.max_linear, max_lateral=self.max_lateral, max_angular=self.max_angular,
            min_scale=self.min_scale,
        )

    @field_validator("deadman")
    @classmethod
    def _deadman(cls, v: str) -> str:
        # Refused, not read as "no dead-man": a blank in a config file must not disable it.
        v = v.strip()
        if not v:
            raise ValueError(f"deadman is empty: name the dead-man button (e.g. BTN_TRIGGER), or {NO_DEADMAN!r} "
                             "to drive without one")
        if v.lower() == NO_DEADMAN:
            return NO_DEADMAN
        parse_code(v)  # an unknown code name is a ValueError naming it
        return v

    def event_source(self) -> EventSource:
        if self.source == "evdev":
            return EvdevSource(self.device)
        if not self.device:
            raise ValueError(f"source {self.source!r} needs device=<path>")
        if self.source == "raw":
            return RawEventSource(self.device)
        return load_recording(self.device)


class JoystickNode:
    def __init__(self, node: Node, s: JoystickSettings):
        self.node, self.s = node, s
        self.ref_key = node.keys.cmd_ref_of(s.source_name)  # its own key: protocol.keys.REF_SOURCES
        self.core = JoystickGateway(s.mapping(), s)  # the settings are a GatewayConfig
        self.source = s.event_source()
        self.waker: FdWaker | None = None
        if s.wake_on_input:
            # A session-local put: delivered to this node's own subscriber only, never sent out.
            wake_key = node.keys.key(f"joystick/wake/{uuid.uuid4().hex[:8]}")
            node.subscribe(wake_key, None, lambda _key, _payload: self.poll(), queue="latest")
            session = node.session
            self.waker = FdWaker(lambda: session.put(wake_key, b"", allowed_destination=zenoh.Locality.SESSION_LOCAL))
        node.every(s.poll_s, self.poll)
        self.poll()

    def poll(self) -> None:
        now = time.monotonic()
        core = self.core
        if core.open_due(now):
            try:
                info = self.source.open()
            except DeviceUnavailable as exc:
                core.on_open_failed(now)
                self.node.ratelog(logging.WARNING, "open", f"no joystick: {exc}; publishing zero, retrying "
                                  f"every {self.s.reconnect_s} s")
            except ModuleNotFoundError as exc:
                core.on_open_failed(now)
                self.node.ratelog(logging.ERROR, "open", f"evdev is not installed ({exc}): pip install "
                                  "'riskfield[robot]'")
            else:
                core.on_open(info, now)
                self.node.log.info("joystick %r open (%s)", info.name, info.path or self.s.source)
        if core.connected:
            try:
                core.on_events(self.source.read())
            except DeviceLost as exc:
                core.on_lost(now)
                self.node.ratelog(logging.ERROR, "lost", f"joystick lost ({exc}); zero command until it is back")
        if self.waker is not None:
            self.waker.watch(self.source.fileno() if core.connected else -1)
            self.waker.drained()
        if core.should_publish(now):
            c = core.command
            self.node.publish(self.ref_key, VelocityCommand(
                linear=(c.vx, c.vy, 0.0), angular=(0.0, 0.0, c.wz), source=self.s.source_name,
                engaged=c.deadman))  # released: the filter's arbitration lets the navigator take over
            core.published(now)
            self.node.stats["deadman"] = float(c.deadman)
            self.node.stats["connected"] = float(core.connected)
            self.node.stats["losses"] = float(core.losses)
            self.node.stats["syn_dropped"] = float(core.syn_dropped)

    def close(self) -> None:
        # Runs after the session closed, so no last zero can be published here: the safety
        # filter's reference timeout (0.2 s) brakes the robot instead.
        if self.waker is not None:
            self.waker.close()
        self.source.close()


def setup(node: Node, s: JoystickSettings) -> JoystickNode:
    return JoystickNode(node, s)


SERVICE = ServiceSpec("joystick", JoystickSettings, setup)
