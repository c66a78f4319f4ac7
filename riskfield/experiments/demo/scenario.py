"""The demo's world: a LIMO in a room with a person, a dog, a ball and furniture.

Teleoperation (the paper's Fig. 5): the operator drives at the ball (low risk), backs off, then
drives at the dog (``animal``, high risk). Navigation (Fig. 6): a loop of four waypoints around
the table; after the first lap a ball is dropped on the path (the unseen obstacle) and the
robot must go round it on the second.
"""

from __future__ import annotations

from typing import Any

ROBOT_START = (-3.5, -1.5, 0.0)
TELEOP_TARGETS = [("ball", -1.4, -1.5), ("dog", -2.7, 1.5)]
LOOP = [(0.6, -1.7), (3.3, -1.7), (3.3, 1.7), (0.6, 1.7)]
UNSEEN = {"class": "ball", "name": "unseen_ball", "position": [1.95, -1.7]}  # on the first leg of lap 2
#: objects whose clearance the report follows, by scene object name → risk class shown
TRACKED = {"ball": "ball (low risk)", "dog": "dog (high risk)", "walker": "person (high risk)",
           "unseen_ball": "unseen ball (low risk)"}


def scenario() -> dict[str, Any]:
    return {
        "name": "demo",
        "room": {"size": [9.0, 6.0], "height": 2.5},
        "robot": {"type": "limo", "start": list(ROBOT_START)},
        "objects": [
            {"class": "ball", "name": "ball", "position": [TELEOP_TARGETS[0][1], TELEOP_TARGETS[0][2]]},
            {"class": "animal", "name": "dog", "position": [TELEOP_TARGETS[1][1], TELEOP_TARGETS[1][2]],
             "yaw": 0.0},
            {"class": "table", "name": "table", "position": [1.95, 0.0]},
            {"class": "chair", "name": "chair", "position": [1.95, 0.75], "yaw": 3.14159},
            {"class": "sofa", "name": "sofa", "position": [-0.8, 2.55]},
            {"class": "cabinet", "name": "cabinet", "position": [4.2, 0.0]},
            {"class": "person", "name": "walker", "position": [-0.4, 0.4],
             "waypoints": [[-0.4, 0.4], [-0.4, 1.4]], "speed": 0.25},
        ],
    }


def navigation_waypoints(laps: float = 1.5) -> list[tuple[float, float]]:
    """Waypoints for ``laps`` laps (a fractional lap ends part way round)."""
    n = round(laps * len(LOOP))
    return [LOOP[i % len(LOOP)] for i in range(n)]
