"""Operator node: a ScriptedOperator publishing ``cmd/ref`` (source ``operator``) from ``state``."""

from __future__ import annotations

import time
from typing import ClassVar

from pydantic import Field

from riskfield.protocol import RobotState, VelocityCommand

from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .operator import OperatorConfig, ScriptedOperator, Target


class OperatorSettings(NodeSettings, OperatorConfig):
    """The scripted operator's ``OperatorConfig`` (flat: ``--set push_s=6``) plus its targets and rates."""

    SERVICE: ClassVar[str] = "operator"

    targets: list[tuple[str, float, float]] = Field(default_factory=list, description="[name, x, y] in visiting order")
    seed: int = Field(default=0, description="draws the operator's speed, aim and noise: one seed, one operator")
    rate_hz: float = Field(default=20.0, gt=0, description="cmd/ref rate (the joystick's)")
    state_timeout_s: float = Field(default=0.5, gt=0, description="no state for this long: zero cmd/ref")


def setup(node: Node, s: OperatorSettings) -> None:
    op = ScriptedOperator([Target(*t) for t in s.targets], s, seed=s.seed)  # the settings are an OperatorConfig
    last: dict[str, object] = {}

    def on_state(st: RobotState) -> None:
        last["state"], last["at"] = st, time.monotonic()

    def tick() -> None:
        st = last.get("state")
        now = time.monotonic()
        if not isinstance(st, RobotState) or now - float(last["at"]) > s.state_timeout_s:
            node.publish(node.keys.cmd_ref_of("operator"), VelocityCommand.zero("operator"))
            return
        v, w, phase = op.command(now, st.position[0], st.position[1], st.yaw)
        node.stats["target_index"] = op.index
        node.publish(node.keys.cmd_ref_of("operator"),
                     VelocityCommand(linear=(v, 0.0, 0.0), angular=(0.0, 0.0, w), source="operator"))
        if phase == "done" and not last.get("done"):
            last["done"] = True
            node.log.info("operator finished all %d targets", len(op.targets))

    node.subscribe(node.keys.state, RobotState, on_state)
    node.every(1.0 / s.rate_hz, tick)


SERVICE = ServiceSpec("operator", OperatorSettings, setup)
