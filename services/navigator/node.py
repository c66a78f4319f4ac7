"""The navigator node: ``nav/goal`` (fifo) + ``state`` (latest) → ``cmd/ref`` at a fixed rate.

It publishes while it has a goal: the CLF command while driving, zeros when the state is
stale or the final waypoint is reached. After arriving it keeps sending zeros for
``stop_hold_s`` and then falls silent, so that a joystick sharing ``cmd/ref`` is not
overridden by an idle navigator.
"""

from __future__ import annotations

import logging
import time
from typing import ClassVar

from pydantic import Field

from riskfield.protocol import NavGoal, RobotState, VelocityCommand

from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .config import NavigatorConfig
from .navigator import Navigator


class NavigatorSettings(NodeSettings):
    SERVICE: ClassVar[str] = "navigator"

    rate_hz: float = Field(20.0, gt=0, le=1000)
    """cmd/ref rate while the navigator has a goal."""
    source: str = "navigator"
    """The source name its commands carry (VelocityCommand.source)."""
    stop_hold_s: float = Field(1.0, ge=0)
    """Zeros are sent this long after arriving, then the navigator falls silent (a joystick may share cmd/ref)."""
    nav: NavigatorConfig = Field(default_factory=NavigatorConfig)
    """The CLF controller and its limits (nav.k_rho, nav.v_max, ...)."""


class NavigatorNode:
    """Glue between the node and the pure ``Navigator`` (kept tiny on purpose)."""

    def __init__(self, node: Node, s: NavigatorSettings):
        self.node, self.s = node, s
        self.ref_key = node.keys.cmd_ref_of(s.source)  # its own key: protocol.keys.REF_SOURCES
        self.core = Navigator(s.nav)
        self._silent_after = float("inf")
        node.subscribe(node.keys.nav_goal, NavGoal, self.on_goal, queue="fifo")
        node.subscribe(node.keys.state, RobotState, self.on_state, queue="latest")
        node.every(1.0 / s.rate_hz, self.tick)

    def on_goal(self, msg: NavGoal) -> None:
        try:
            self.core.set_goal(msg.waypoints, msg.tolerance, msg.loop)
        except ValueError as exc:
            self.node.ratelog(logging.WARNING, "goal", f"rejected a goal: {exc}")
            return
        self._silent_after = float("inf")
        self.node.log.info("new goal: %d waypoint(s), tolerance %.2f m, loop %s",
                           msg.waypoints.shape[0], msg.tolerance, msg.loop)

    def on_state(self, msg: RobotState) -> None:
        self.core.set_state(msg.position, msg.orientation, msg.linear_velocity, time.monotonic())

    def tick(self) -> None:
        now = time.monotonic()
        if self.core.goals_received == 0 or now > self._silent_after:
            return
        cmd = self.core.step(now)
        if cmd.reason == "arrived" and self._silent_after == float("inf"):
            self._silent_after = now + self.s.stop_hold_s
            self.node.log.info("final waypoint reached")
        elif cmd.reason == "stale_state":
            self.node.ratelog(logging.WARNING, "stale", "no fresh robot state: commanding zero")
        seq = self.core.sequencer
        self.node.stats.update(waypoint=seq.index, laps=seq.laps, reached=seq.reached,
                               distance_to_target=self.core.distance_to_target(),
                               driving=float(cmd.reason == "driving"), escapes=self.core.escapes,
                               escaping=float(self.core.escaping))
        self.node.publish(self.ref_key,
                          VelocityCommand(linear=cmd.linear, angular=cmd.angular, source=self.s.source))


def setup(node: Node, settings: NavigatorSettings) -> NavigatorNode:
    return NavigatorNode(node, settings)


SERVICE = ServiceSpec("navigator", NavigatorSettings, setup)
