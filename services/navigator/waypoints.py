"""Waypoint sequencing: which goal the nominal controller drives to next.

A waypoint counts as reached when the robot is within ``tolerance`` of it (in the plane for
ground robots, in 3-D otherwise). Reaching a waypoint advances to the next one; after the
last one the sequence either wraps around (``loop``, counting laps) or is finished, and a
finished sequence asks for a stop until a new goal arrives.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class WaypointSequencer:
    planar: bool = True
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    tolerance: float = 0.1
    loop: bool = False
    index: int = 0
    laps: int = 0
    reached: int = 0
    finished: bool = True

    def set_goal(self, waypoints: np.ndarray, tolerance: float, loop: bool) -> None:
        """Start a new sequence (replaces the current one)."""
        w = np.array(waypoints, dtype=float).reshape(-1, 3)  # a copy: decoded arrays are read-only views
        if w.shape[0] == 0:
            raise ValueError("at least one waypoint is required")
        if not np.isfinite(w).all():
            raise ValueError("waypoints must be finite")
        if not (tolerance > 0 and np.isfinite(tolerance)):
            raise ValueError("tolerance must be positive")
        self.waypoints, self.tolerance, self.loop = w, float(tolerance), bool(loop)
        self.index, self.laps, self.reached, self.finished = 0, 0, 0, False

    @property
    def active(self) -> bool:
        return not self.finished and self.waypoints.shape[0] > 0

    @property
    def target(self) -> np.ndarray | None:
        return self.waypoints[self.index] if self.active else None

    def distance(self, position: np.ndarray, waypoint: np.ndarray) -> float:
        d = np.asarray(position, dtype=float)[:3] - waypoint
        return float(np.hypot(d[0], d[1]) if self.planar else np.linalg.norm(d))

    def update(self, position: np.ndarray) -> np.ndarray | None:
        """Advance past every waypoint reached from ``position``; the current target, or
        ``None`` once the final waypoint of a non-looping sequence is reached."""
        # At most one full pass per call: a loop whose waypoints all lie within the tolerance
        # would otherwise spin forever.
        for _ in range(self.waypoints.shape[0]):
            if not self.active or self.distance(position, self.waypoints[self.index]) > self.tolerance:
                break
            self.reached += 1
            if self.index + 1 < self.waypoints.shape[0]:
                self.index += 1
            elif self.loop:
                self.index, self.laps = 0, self.laps + 1
            else:
                self.finished = True
        return self.target
