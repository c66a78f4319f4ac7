"""The joystick gateway core: input events → the reference command, and when to publish it.

Events are applied per evdev packet: changes collect until ``SYN_REPORT`` and then take effect
together (a diagonal stick move is one change, not two). After ``SYN_DROPPED`` the kernel
lost events, possibly a dead-man release, so the gateway drops the rest of that packet and
treats the dead-man as released until it is seen pressed again.

Publishing: at ``rate_hz`` always (the safety filter treats a silent reference as stale and
brakes), plus at once when a packet changes the command, so an operator's input reaches the
robot without waiting for the next tick. Zero is published while the dead-man is released,
the device is missing, or it was lost; the node keeps trying to open it every ``reconnect_s``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from pydantic import BaseModel, ConfigDict, Field

from .mapping import EV_ABS, EV_KEY, EV_SYN, SYN_DROPPED, SYN_REPORT, JoystickMapping, StickCommand, command
from .source import DeviceInfo, InputEvent


class GatewayConfig(BaseModel):
    """The gateway core's timing (the stick mapping is ``JoystickMapping``)."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    rate_hz: float = Field(default=50.0, gt=0, allow_inf_nan=False, description=(
        "cmd/ref rate, always (a changed stick also publishes at once)"))
    reconnect_s: float = Field(default=1.0, gt=0, allow_inf_nan=False, description=(
        "a missing or lost device is reopened this often"))


class JoystickGateway:
    def __init__(self, mapping: JoystickMapping | None = None, config: GatewayConfig | None = None):
        self.base_mapping = mapping or JoystickMapping()
        self.mapping = self.base_mapping
        self.config = config or GatewayConfig()
        self.connected = False
        self.device = ""
        self.command = StickCommand()
        self.axes: dict[int, float] = {}
        self.buttons: dict[int, int] = {}
        self._pending: dict[tuple[int, int], int] = {}
        self._dropping = False
        self._changed = True  # publish once right away
        self._last_pub = -math.inf
        self._next_open = -math.inf
        self.opens = 0
        self.losses = 0
        self.packets = 0
        self.syn_dropped = 0

    # -- device -------------------------------------------------------------------------------
    def open_due(self, now: float) -> bool:
        return not self.connected and now >= self._next_open

    def on_open_failed(self, now: float) -> None:
        self._next_open = now + self.config.reconnect_s

    def on_open(self, info: DeviceInfo, now: float) -> None:
        self.connected = True
        self.device = info.name
        self.opens += 1
        self.mapping = self.base_mapping.with_ranges(info.ranges)
        self.axes = {k: float(v) for k, v in info.axes.items()}
        self.buttons = dict(info.buttons)
        self._pending.clear()
        self._dropping = False
        self._update()

    def on_lost(self, now: float) -> None:
        if self.connected:
            self.losses += 1
        self.connected = False
        self._next_open = now + self.config.reconnect_s
        self.axes.clear()
        self.buttons.clear()
        self._pending.clear()
        self._update()

    # -- events -------------------------------------------------------------------------------
    def on_events(self, events: Iterable[InputEvent]) -> bool:
        """Apply events; True when the command changed (the node then publishes at once)."""
        before = self.command
        for e in events:
            if e.type == EV_SYN:
                if e.code == SYN_REPORT:
                    if not self._dropping:
                        for (ty, code), value in self._pending.items():
                            (self.axes if ty == EV_ABS else self.buttons)[code] = value
                        self.packets += 1
                    self._pending.clear()
                    self._dropping = False
                    self._update()
                elif e.code == SYN_DROPPED:
                    self.syn_dropped += 1
                    self._pending.clear()
                    self._dropping = True
                    if self.mapping.deadman is not None:
                        self.buttons[self.mapping.deadman] = 0
                    self._update()
            elif e.type in (EV_ABS, EV_KEY) and not self._dropping:
                self._pending[(e.type, e.code)] = e.value
        return self.command != before

    def _update(self) -> None:
        new = command(self.mapping, self.axes, self.buttons) if self.connected else StickCommand()
        if new != self.command:
            self._changed = True
        self.command = new

    # -- publishing ---------------------------------------------------------------------------
    def should_publish(self, now: float) -> bool:
        return self._changed or now - self._last_pub >= 1.0 / self.config.rate_hz

    def published(self, now: float) -> None:
        self._changed = False
        self._last_pub = now
