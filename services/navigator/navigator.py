"""The navigator core: waypoint sequence + CLF law + staleness guard → one reference command.

Pure: the node feeds it goals and states with the time they arrived and asks for a command
at a fixed rate. It commands zero whenever it cannot drive safely towards a goal: no goal,
the final waypoint reached, or no state newer than ``state_timeout_s``.

Deadlock escape. A CLF reference filtered by a CBF has a well-known equilibrium: an obstacle
straight between robot and goal, the filter cancelling exactly the reference's approach. The
robot then stands still forever (the paper's loop experiment needs it to go round an unseen
ball). The navigator sees this without a map: the distance to the current target has not
dropped by ``stall_progress`` within ``stall_s``. It then drives for ``escape_s`` to a side
sub-goal, ``escape_distance`` away at ``escape_angle_deg`` off the line to the target, and
resumes; the side alternates on each new stall (left first), so a blocked side is not
retried forever. The safety filter still has the last word on every command.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.transforms import world_to_body, yaw_of
from .config import NavigatorConfig
from .waypoints import WaypointSequencer


@dataclass(frozen=True)
class NavCommand:
    """Body-frame linear (m/s) and angular (rad/s) command, and why it is what it is."""

    linear: tuple[float, float, float]
    angular: tuple[float, float, float]
    reason: str  # "driving", "idle" (no goal), "arrived", "stale_state"

    @property
    def is_zero(self) -> bool:
        return not any(self.linear) and not any(self.angular)


ZERO = (0.0, 0.0, 0.0)


class Navigator:
    def __init__(self, config: NavigatorConfig | None = None):
        self.config = config or NavigatorConfig()
        self.sequencer = WaypointSequencer(planar=self.config.model == "unicycle")
        self._unicycle = self.config.unicycle()
        self._di = self.config.double_integrator()
        self._position: np.ndarray | None = None
        self._orientation = np.array([0.0, 0.0, 0.0, 1.0])
        self._velocity = np.zeros(3)
        self._state_t = -np.inf
        self.goals_received = 0
        self._progress: list[tuple[float, float]] = []  # (t, distance to target) while driving
        self._escape_until = -np.inf
        self._escape_goal: np.ndarray | None = None
        self._side = 1.0
        self.escapes = 0

    def set_goal(self, waypoints: np.ndarray, tolerance: float, loop: bool) -> None:
        self.sequencer.set_goal(waypoints, tolerance, loop)
        self.goals_received += 1
        self._progress.clear()
        self._escape_until = -np.inf

    @property
    def escaping(self) -> bool:
        return self._escape_goal is not None

    def set_state(self, position: np.ndarray, orientation: np.ndarray, velocity: np.ndarray, t: float) -> None:
        p, q, v = (np.array(a, dtype=float) for a in (position, orientation, velocity))
        if not (np.isfinite(p).all() and np.isfinite(q).all() and np.isfinite(v).all()):
            raise ValueError("state must be finite")
        self._position, self._orientation, self._velocity, self._state_t = p, q, v, float(t)

    def state_fresh(self, t: float) -> bool:
        return self._position is not None and t - self._state_t <= self.config.state_timeout_s

    def distance_to_target(self) -> float:
        target = self.sequencer.target
        if target is None or self._position is None:
            return 0.0
        return self.sequencer.distance(self._position, target)

    def step(self, t: float) -> NavCommand:
        """The reference command at time ``t`` (same clock as ``set_state``)."""
        if not self.sequencer.active:
            return NavCommand(ZERO, ZERO, "arrived" if self.sequencer.reached else "idle")
        if not self.state_fresh(t):
            return NavCommand(ZERO, ZERO, "stale_state")
        assert self._position is not None
        index = self.sequencer.index
        target = self.sequencer.update(self._position)
        if target is None:
            return NavCommand(ZERO, ZERO, "arrived")
        if self.sequencer.index != index:
            self._progress.clear()
        target = self._escape(t, target) if self.config.escape else target
        if self.config.model == "unicycle":
            v, w = self._unicycle.command(self._position, yaw_of(self._orientation), target)
            return NavCommand((v, 0.0, 0.0), (0.0, 0.0, w), "driving")
        v_des = self._di.desired_velocity(self._position, target)
        vb = world_to_body(self._orientation, v_des)
        return NavCommand((float(vb[0]), float(vb[1]), float(vb[2])), ZERO, "driving")

    def _escape(self, t: float, target: np.ndarray) -> np.ndarray:
        """The point to drive to now: ``target``, or a side sub-goal while escaping a stall."""
        c = self.config
        assert self._position is not None
        if self._escape_goal is not None:
            if t < self._escape_until:
                return self._escape_goal
            self._escape_goal = None
            self._progress.clear()
        d = self.sequencer.distance(self._position, target)
        self._progress.append((t, d))
        while len(self._progress) > 1 and self._progress[1][0] <= t - c.stall_s:
            self._progress.pop(0)
        t0, d0 = self._progress[0]
        if t - t0 < c.stall_s - 1e-9 or d0 - d >= c.stall_progress:
            return target
        # Stalled: a sub-goal to the side of the line to the target (in the horizontal plane).
        to = target[:2] - self._position[:2]
        n = float(np.hypot(*to))
        u = to / n if n > 1e-9 else np.array([1.0, 0.0])
        a = self._side * np.radians(c.escape_angle_deg)
        r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ u
        goal = self._position.copy()
        goal[:2] += c.escape_distance * r
        self._escape_goal, self._escape_until = goal, t + c.escape_s
        self._side = -self._side
        self.escapes += 1
        self._progress.clear()
        return goal
