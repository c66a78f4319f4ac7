"""Admission of robot states by physical continuity (pure: every time is an argument).

A ``state`` sample says where the robot is. A robot cannot be farther from where it last was than
its top speed allows in the time between the two samples, so a sample that jumps farther is a
fault (a glitching odometry, a forged or misrouted publisher, a replay) and is refused: the mapping
node would otherwise recentre its rolling volume past every voxel and lose the map, and the safety
filter would plan from a position the robot is not at. The rule, with ``d`` the distance from the
last admitted position and ``dt`` the time since it (the larger of the stamps' and the arrivals'
difference, so neither a burst after a network stall nor a delayed stamp refuses real motion):

.. math::  d \\le v_{max} \\, dt + \\epsilon

A sample stamped more than ``clock_tolerance_s`` after the local wall clock is refused as well (its
clock is wrong, and it would stretch ``dt``); neither refusal moves the reference.

A deliberate jump (relocalisation, a reset simulation, an odometry reset) is announced on
``{prefix}/{robot}/state/relocalise`` with the new state: ``relocalise`` takes it as the new
reference. Without an announcement the gate heals by itself once ``v_max · dt`` covers the jump
(about 5 s for a 5 m jump at the LIMO's 1 m/s), meanwhile the filter brakes on ``stale_state``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Annotated

import numpy as np
from pydantic import BaseModel, Field

from riskfield.protocol.platforms import LIMO

FUTURE = "future_state"
JUMP = "state_jump"


class StateGateSettings(BaseModel):
    """The gate's settings, shared by the nodes that take ``state`` (mapping, safety filter)."""

    state_max_speed: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False, description=(
        "top speed of the robot (m/s) a state sample is judged by: one that moved farther than "
        "state_max_speed · dt + state_jump_tolerance_m since the last admitted sample is refused "
        "(default: the LIMO's, riskfield.protocol.platforms; raise it for a faster vehicle)"))] = LIMO.max_linear
    state_jump_tolerance_m: Annotated[float, Field(ge=0, le=100, allow_inf_nan=False, description=(
        "distance (m) a state sample may move beyond what state_max_speed allows: odometry noise "
        "and corrections, timing jitter"))] = 0.25


@dataclass
class StateGate:
    """Admits or refuses state samples; counts the refusals by reason in ``refused``."""

    max_speed: float = LIMO.max_linear
    tolerance_m: float = 0.25
    clock_tolerance_s: float = 0.1
    refused: dict[str, int] = field(default_factory=dict)
    _last: tuple[np.ndarray, int, float] | None = None  # position, stamp (ns), arrival (monotonic s)

    @classmethod
    def of(cls, settings: StateGateSettings, clock_tolerance_s: float) -> StateGate:
        return cls(settings.state_max_speed, settings.state_jump_tolerance_m, clock_tolerance_s)

    def admit(self, position: object, stamp_ns: int, now: float, wall_ns: int) -> str | None:
        """None when the sample is admitted (it becomes the reference), else why it is refused."""
        p = np.asarray(position, dtype=np.float64).reshape(3)
        reason = self._check(p, stamp_ns, now, wall_ns)
        if reason is not None:
            self.refused[reason] = self.refused.get(reason, 0) + 1
            return reason
        self._last = (p, int(stamp_ns), now)
        return None

    def relocalise(self, position: object, stamp_ns: int, now: float, wall_ns: int) -> str | None:
        """An announced jump: the new reference whatever the distance (a future stamp is still refused)."""
        p = np.asarray(position, dtype=np.float64).reshape(3)
        if self._future(stamp_ns, wall_ns):
            self.refused[FUTURE] = self.refused.get(FUTURE, 0) + 1
            return FUTURE
        self._last = (p, int(stamp_ns), now)
        return None

    def allowance_m(self, stamp_ns: int, now: float) -> float:
        """How far a sample stamped ``stamp_ns`` arriving at ``now`` may be from the reference."""
        if self._last is None:
            return math.inf
        _, stamp0, at0 = self._last
        dt = max((int(stamp_ns) - stamp0) * 1e-9, now - at0, 0.0)
        return self.max_speed * dt + self.tolerance_m

    def _future(self, stamp_ns: int, wall_ns: int) -> bool:
        return (int(stamp_ns) - int(wall_ns)) * 1e-9 > self.clock_tolerance_s

    def _check(self, p: np.ndarray, stamp_ns: int, now: float, wall_ns: int) -> str | None:
        if self._future(stamp_ns, wall_ns):
            return FUTURE
        if self._last is not None and not float(np.linalg.norm(p - self._last[0])) <= self.allowance_m(stamp_ns, now):
            return JUMP  # written as "not <=" so a NaN distance is refused too
        return None

    @property
    def refused_total(self) -> int:
        return sum(self.refused.values())


def report_refused(node, gate: StateGate, reason: str, position, stamp_ns: int, kept: str) -> None:
    """Count a refused state in the node's status and say so, rate-limited; ``kept`` says what
    stays in force (the nodes' one wording of a refusal)."""
    st = node.stats
    st["state_refused"] = gate.refused_total
    st[f"state_refused_{reason}"] = gate.refused[reason]
    node.ratelog(logging.WARNING, f"state_refused:{reason}",
                 f"refused a state at {[round(float(v), 3) for v in position]} ({reason}, stamp {stamp_ns}): {kept}")
