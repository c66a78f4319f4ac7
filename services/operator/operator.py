"""Scripted teleoperation with human-like variability, for the paper's teleop experiment.

The operator drives a unicycle robot at each target in turn, the way a person does with a
joystick: aim at the target and push forward for ``push_s`` seconds (the safety filter decides
how close the robot really gets), back off, turn towards the next target, repeat. Variability
comes from a per-run speed scale, an aim offset, a reaction delay (the operator acts on a
state that is ``reaction_s`` old) and Ornstein–Uhlenbeck noise on both sticks — all drawn
from one seed, so a run is reproducible and twelve seeds make twelve different operators.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from ..geometry.transforms import wrap_angle

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


@dataclass(frozen=True)
class Target:
    name: str
    x: float
    y: float


class OperatorConfig(BaseModel):
    """How the scripted operator drives: its speed, aim, reaction and stick noise, and its rhythm."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    cruise_speed: Pos = Field(default=0.45, description="forward push (m/s) before the per-run scale")
    speed_spread: Annotated[float, Field(ge=0, lt=1)] = Field(default=0.2, description=(
        "the per-run speed scale is drawn from 1 ± this"))
    heading_gain: Pos = Field(default=1.8, description="yaw rate (rad/s) per rad of heading error")
    max_turn: Pos = Field(default=1.2, description="|yaw rate| of the stick (rad/s)")
    aim_spread: NonNeg = Field(default=0.08, description="std (m) of the lateral aim offset per target")
    reaction_s: NonNeg = Field(default=0.2, description="the operator acts on a state this old (s)")
    noise_v: NonNeg = Field(default=0.04, description="stationary std (m/s) of the forward stick's OU noise")
    noise_w: NonNeg = Field(default=0.12, description="stationary std (rad/s) of the turn stick's OU noise")
    noise_tau_s: Pos = Field(default=0.7, description="time constant (s) of the stick noise")
    push_s: Pos = Field(default=7.0, description="how long the operator keeps pushing at a target (s)")
    backoff_s: NonNeg = Field(default=1.5, description="how long it backs off after a push (s)")
    backoff_speed: NonNeg = Field(default=0.3, description="backing-off speed (m/s)")
    turn_tolerance: Pos = Field(default=0.15, description=(
        "facing the next target (rad) when the heading error is below this"))


@dataclass
class _Noise:
    """Ornstein–Uhlenbeck process with stationary std ``sigma`` and time constant ``tau``."""

    sigma: float
    tau: float
    rng: np.random.Generator
    x: float = 0.0

    def step(self, dt: float) -> float:
        a = math.exp(-dt / self.tau)
        self.x = a * self.x + self.sigma * math.sqrt(1 - a * a) * float(self.rng.standard_normal())
        return self.x


@dataclass
class ScriptedOperator:
    """Call ``command(t, x, y, yaw)`` at the joystick rate; it returns (v, ω) and the phase."""

    targets: list[Target]
    config: OperatorConfig = field(default_factory=OperatorConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        c = self.config
        self.speed = c.cruise_speed * float(rng.uniform(1 - c.speed_spread, 1 + c.speed_spread))
        self.aims = [float(rng.normal(0.0, c.aim_spread)) for _ in self.targets]
        self._nv = _Noise(c.noise_v, c.noise_tau_s, rng)
        self._nw = _Noise(c.noise_w, c.noise_tau_s, rng)
        self._seen: deque[tuple[float, float, float, float]] = deque()
        self.index = 0
        self.phase = "turn" if self.targets else "done"
        self._phase_t0: float | None = None
        self._last_t: float | None = None

    @property
    def target(self) -> Target | None:
        return self.targets[self.index] if self.index < len(self.targets) else None

    def _perceived(self, t: float, x: float, y: float, yaw: float) -> tuple[float, float, float]:
        self._seen.append((t, x, y, yaw))
        while len(self._seen) > 1 and self._seen[1][0] <= t - self.config.reaction_s:
            self._seen.popleft()
        return self._seen[0][1:]

    def _enter(self, phase: str, t: float) -> None:
        self.phase, self._phase_t0 = phase, t

    def command(self, t: float, x: float, y: float, yaw: float) -> tuple[float, float, str]:
        c = self.config
        dt = 0.0 if self._last_t is None else max(0.0, t - self._last_t)
        self._last_t = t
        if self._phase_t0 is None:
            self._phase_t0 = t
        nv, nw = self._nv.step(dt), self._nw.step(dt)
        tgt = self.target
        if tgt is None:
            self.phase = "done"
            return 0.0, 0.0, self.phase
        px, py, pyaw = self._perceived(t, x, y, yaw)
        # aim at a point offset sideways from the target, as people never aim exactly
        bearing = math.atan2(tgt.y - py, tgt.x - px)
        aim_x = tgt.x - math.sin(bearing) * self.aims[self.index]
        aim_y = tgt.y + math.cos(bearing) * self.aims[self.index]
        err = wrap_angle(math.atan2(aim_y - py, aim_x - px) - pyaw)
        w = float(np.clip(c.heading_gain * err, -c.max_turn, c.max_turn))
        elapsed = t - self._phase_t0
        if self.phase == "turn":
            if abs(err) < c.turn_tolerance:
                self._enter("approach", t)
            return 0.0, w + nw, self.phase
        if self.phase == "approach":
            if elapsed >= c.push_s:
                self._enter("backoff", t)
                return 0.0, 0.0, self.phase
            v = self.speed * max(0.0, math.cos(err))
            return max(0.0, v + nv), w + nw, self.phase
        if self.phase == "backoff":
            if elapsed >= c.backoff_s:
                self.index += 1
                self._enter("turn" if self.target else "done", t)
                return 0.0, 0.0, self.phase
            return -c.backoff_speed, nw, self.phase
        return 0.0, 0.0, self.phase
