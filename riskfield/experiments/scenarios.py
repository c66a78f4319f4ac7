"""The worlds of the hardware-style experiments, and their ground truth.

* **The demo's room** (``riskfield demo``): a LIMO in a room with a person, a dog, a ball and
  furniture. Teleoperation (the paper's Fig. 5): the operator drives at the ball (low risk),
  backs off, then drives at the dog (``animal``, high risk). Navigation (Fig. 6): a loop of four
  waypoints around the table; after the first lap a ball is dropped on the path (the unseen
  obstacle) and the robot must go round it on the second.
* **The teleop cases** (``riskfield bench teleop``): the simulator's built-in ``teleop_ball`` and
  ``teleop_dog`` rooms, one obstacle straight ahead of the robot.
* **The square room** (``riskfield bench navigation``): a 7 × 7 m room, a table in the middle, a
  chair and a ball near a 4 m square of corners; the unseen ball lands on the square's first side.

Ground truth is the simulator's own geometry (open3d signed distances to the object meshes):
*clearance* is the distance from the robot to an obstacle's surface, *a collision* an episode
of clearance below zero.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from riskfield.protocol import RiskConfig
from riskfield.services.simulator.scenario import ObjectSpec, build_scene, load_scenario, object_from_spec
from riskfield.services.simulator.scene import Scene

# -- the demo's room ----------------------------------------------------------------------------

ROBOT_START = (-3.5, -1.5, 0.0)
TELEOP_TARGETS = [("ball", -1.4, -1.5), ("dog", -2.7, 1.5)]
LOOP = [(0.6, -1.7), (3.3, -1.7), (3.3, 1.7), (0.6, 1.7)]
UNSEEN = {"class": "ball", "name": "unseen_ball", "position": [1.95, -1.7]}  # on the first leg of lap 2
#: objects whose clearance the report follows, by scene object name → risk class shown
TRACKED = {"ball": "ball (low risk)", "dog": "dog (high risk)", "walker": "person (high risk)",
           "unseen_ball": "unseen ball (low risk)"}


def scenario() -> dict[str, Any]:
    """The demo's room as a simulator scenario."""
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
    """Waypoints for ``laps`` laps of the demo's loop (a fractional lap ends part way round)."""
    n = round(laps * len(LOOP))
    return [LOOP[i % len(LOOP)] for i in range(n)]


# -- the teleop cases -----------------------------------------------------------------------------

#: obstacle class → (the simulator's built-in scenario, the obstacle's object name)
TELEOP_CASES = {"ball": ("teleop_ball", "ball"), "dog": ("teleop_dog", "dog")}

# -- the square room ------------------------------------------------------------------------------

SQUARE_CORNERS = np.array([[2.0, -2.0, 0.0], [2.0, 2.0, 0.0], [-2.0, 2.0, 0.0], [-2.0, -2.0, 0.0]])
SQUARE_START = (-2.0, -2.0, 0.0)
SQUARE_UNSEEN = {"class": "ball", "name": "unseen_ball", "position": [2.0, 0.0]}
SQUARE_ROOM = {
    "name": "navigation_loop", "room": {"size": [7.0, 7.0]},
    "robot": {"type": "limo", "start": list(SQUARE_START)},
    "objects": [
        {"class": "table", "name": "table", "position": [0.0, 0.0]},
        {"class": "chair", "name": "chair", "position": [2.8, 0.0], "yaw": math.pi},
        {"class": "ball", "name": "ball", "position": [0.0, 2.6]},
    ],
}

# -- ground truth -----------------------------------------------------------------------------------

#: heights (m) of the LIMO's body at which the demo's clearance is measured
BODY_HEIGHTS = (0.08, 0.2)


def placed_object(spec: dict[str, Any]):
    """A scene object from a spawn spec (what ``sim/spawn`` places), as the simulator builds it."""
    return object_from_spec(ObjectSpec.model_validate(spec), spec["name"])


def scene_objects(source: str | Path | dict[str, Any], extra: Sequence[dict[str, Any]] = ()) -> dict[str, Any]:
    """Every object of a scenario but floor and ceiling, plus ``extra`` spawn specs, by name."""
    full = build_scene(load_scenario(source))
    objs = {o.name: o for o in full.objects if o.class_name not in ("floor", "ceiling")}
    for spec in extra:
        objs[spec["name"]] = placed_object(spec)
    return objs


def obstacle_distance(source: str | Path | dict[str, Any], name: str) -> Callable[[np.ndarray], np.ndarray]:
    """Distance (m) from planar points to one obstacle's surface, at the obstacle's mid-height."""
    obj = build_scene(load_scenario(source))[name]
    only = Scene([obj])
    v = obj.world_mesh(0.0)[0]
    z_mid = 0.5 * float(v[:, 2].min() + v[:, 2].max())

    def distance(xy: np.ndarray) -> np.ndarray:
        pts = np.column_stack([xy, np.full(len(xy), z_mid)])
        return np.asarray(only.at(0.0).distance(pts), dtype=float)

    return distance


def risky_clearance(source: str | Path | dict[str, Any], extra: Sequence[dict[str, Any]] = (),
                    height: float = 0.15) -> Callable[[np.ndarray], np.ndarray]:
    """Distance (m) from the robot centre (at body ``height``) to the nearest surface of an object
    the filter avoids (risk group > 0: not walls or floor), ``extra`` spawn specs included."""
    scene = build_scene(load_scenario(source))
    lut = RiskConfig().label_to_group()
    only = Scene([o for o in scene.objects if lut[int(o.label)] > 0] + [placed_object(s) for s in extra])

    def clearance(xy: np.ndarray) -> np.ndarray:
        pts = np.column_stack([xy, np.full(len(xy), height)])
        return np.asarray(only.at(0.0).distance(pts), dtype=float)

    return clearance


def clearance_series(scene_for: Callable[[str, float], Any], names: Sequence[str], t: np.ndarray, xy: np.ndarray,
                     radius: float, t_sim0: float = 0.0) -> dict[str, np.ndarray]:
    """Clearance to each named object along a trajectory: the signed distance from the robot's
    centre to the object's surface, smallest over ``BODY_HEIGHTS``, minus the robot ``radius``.

    ``scene_for(name, t_sim)`` returns an object with ``signed_distance(points)``; moving
    objects are evaluated in 0.25 s bins of simulated time.
    """
    out: dict[str, np.ndarray] = {}
    for name in names:
        d = np.full(len(t), np.inf)
        bins = np.floor((t - t_sim0) / 0.25).astype(int)
        for b in np.unique(bins):
            sel = bins == b
            scene = scene_for(name, max(0.0, (b + 0.5) * 0.25))
            if scene is None:
                continue
            best = np.full(int(sel.sum()), np.inf)
            for z in BODY_HEIGHTS:
                pts = np.column_stack([xy[sel], np.full(int(sel.sum()), z)])
                best = np.minimum(best, np.asarray(scene.signed_distance(pts), dtype=float))
            d[sel] = best
        out[name] = d - radius
    return out


def episodes(mask: np.ndarray) -> int:
    """Number of separate runs of True in a boolean series."""
    m = np.asarray(mask, dtype=bool)
    return int(np.count_nonzero(m[1:] & ~m[:-1]) + (1 if m.size and m[0] else 0))


def collisions(clearance: np.ndarray) -> int:
    """Collisions along a trajectory: separate episodes of negative clearance."""
    return episodes(np.asarray(clearance) < 0)
