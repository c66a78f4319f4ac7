"""The paper's navigation experiment (Fig. 6), as ``riskfield demo`` and ``riskfield bench
navigation`` run it: the navigator drives a loop of waypoints on the live semantic ESDF, then an
obstacle no camera has seen yet is dropped on the path and the robot must go round it.

* **completion**: every waypoint reached (within the goal's tolerance, in the plane) before the
  time allowed; progress is followed on the robot's *recorded* states with the navigator's own
  rule (``WaypointSequencer``), so it does not trust the navigator's report of itself;
* **deviation**: planar distance from the driven path to the nominal loop (a closed polyline);
* **clearance** and **collisions**: ground truth, see ``scenarios``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from riskfield.protocol import Keys, NavGoal
from riskfield.services.navigator.waypoints import WaypointSequencer

from .stack import publish


def as_waypoints(points: Sequence[Sequence[float]] | np.ndarray) -> np.ndarray:
    """(N, 3) waypoints from planar (x, y) or (x, y, z) points."""
    p = np.asarray(points, dtype=float)
    return np.column_stack([p[:, :2], p[:, 2] if p.shape[1] > 2 else np.zeros(len(p))])


def send_goal(session: Any, keys: Keys, waypoints: np.ndarray, tolerance: float) -> None:
    """Give the navigator a (non-looping) sequence of waypoints."""
    publish(session, keys.nav_goal, NavGoal(waypoints=as_waypoints(waypoints), tolerance=tolerance, loop=False))


def place_unseen(session: Any, keys: Keys, spec: dict[str, Any]) -> None:
    """Drop an object into the running simulation (``sim/spawn``): the unseen obstacle."""
    publish(session, keys.sim_spawn, json.dumps(spec).encode())


@dataclass
class Drive:
    """How one goal went: completion, waypoints reached, seconds taken (None if not completed)."""

    completed: bool
    reached: int
    elapsed_s: float
    lap_time_s: float | None


def drive(session: Any, keys: Keys, rec: Any, waypoints: np.ndarray, tolerance: float, timeout_s: float,
          on_reached: Callable[[int], None] | None = None) -> Drive:
    """Send ``waypoints`` and follow the robot's recorded ``state`` (a ``stack.Recorder``) until
    the last one is reached or ``timeout_s`` passes; ``on_reached(n)`` is called whenever the
    count of reached waypoints grows."""
    seq = WaypointSequencer(planar=True)
    w = as_waypoints(waypoints)
    seq.set_goal(w, tolerance, loop=False)
    seen = len(rec.snapshot("state"))
    send_goal(session, keys, w, tolerance)
    t0 = time.monotonic()
    reached = 0
    while time.monotonic() - t0 < timeout_s and not seq.finished:
        time.sleep(0.1)  # the poll period of the recorded states
        states = rec.snapshot("state")
        for _, st in states[seen:]:
            seq.update(np.array(st.position))
        seen = len(states)
        if seq.reached > reached:
            reached = seq.reached
            if on_reached is not None:
                on_reached(reached)
    elapsed = time.monotonic() - t0
    return Drive(bool(seq.finished), seq.reached, elapsed, elapsed if seq.finished else None)


def polyline_distance(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Planar distance of each point to the closed polyline through ``corners``."""
    p = np.asarray(points, dtype=float)[:, None, :2]
    c = np.asarray(corners, dtype=float)[:, :2]
    a = c[None]
    b = np.roll(c, -1, axis=0)[None]
    ab = b - a
    s = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[..., None] * ab), axis=-1).min(axis=1)
