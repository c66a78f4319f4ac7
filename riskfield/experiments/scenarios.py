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
* **The crowd** (``riskfield bench crowd``): a 12 × 6 m room, a LIMO driven straight down it, people
  spawned as the drive starts who cross, come head-on, overtake or stop and turn in its way
  (``crowd_case``); the demo's crossing walker (``CROSSER``) is spawned the same way.

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
from riskfield.protocol.platforms import LIMO
from riskfield.services.simulator.scenario import ObjectSpec, build_scene, load_scenario, object_from_spec
from riskfield.services.simulator.scene import Scene

# -- the demo's room ----------------------------------------------------------------------------

ROBOT_START = (-3.5, -1.5, 0.0)
TELEOP_TARGETS = [("ball", -1.4, -1.5), ("dog", -2.7, 1.5)]
LOOP = [(0.6, -1.7), (3.3, -1.7), (3.3, 1.7), (0.6, 1.7)]
UNSEEN = {"class": "ball", "name": "unseen_ball", "position": [1.95, -1.7]}  # on the first leg of lap 2
#: a person who crosses the loop's first leg (y = -1.7) at 1.2 m/s while the robot drives it: spawned
#: when the robot reaches the leg's start, waits 1.5 s (in view once the robot faces along the leg),
#: walks from inside the loop to the south wall and stays there, 1 m off the leg
CROSSER = {"class": "person", "name": "crosser", "position": [2.4, -0.75], "waypoints": [[2.4, -0.75], [2.4, -2.7]],
           "waits": [1.5, 0.0], "speed": 1.2, "motion": "once"}
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


# -- the crowd ------------------------------------------------------------------------------------
#
# ``riskfield bench crowd``: a LIMO driven straight ahead (+x) at a constant reference through a
# long empty room while people walk into its way. The walkers are spawned (``sim/spawn``) when the
# drive starts, so their motion clock and the drive's start together: a design is a timed plan. Each
# one is a *conflict*: had the robot kept its reference speed it would have touched the person
# (``tests/experiments/test_crowd.py`` checks every default case on the nominal trajectory, and that
# each walker is in the camera's view at least 1 s before that nominal contact).

#: The camera at half the default resolution: at 512 × 384 the pipeline's content age passes the
#: filter's staleness bound (0.4 s) on this shared 2-core machine and the robot only ever brakes;
#: at 256 × 192 it stays near 0.13 s (measured under a load of 13).
CROWD_ROOM = {"name": "crowd", "room": {"size": [12.0, 6.0]}, "robot": {"type": "limo", "start": [-4.5, 0.0, 0.0]},
              "camera": {"width": 256, "height": 192, "hfov_deg": 90.0}}
CROWD_START = (-4.5, 0.0, 0.0)
#: the operator's reference (m/s), straight ahead
CROWD_V_REF = 0.5
CROWD_KINDS = ("crossing", "head_on", "overtaking", "stop_and_turn")
CROWD_SPEEDS = (0.8, 1.5)
#: the camera's horizontal field of view (deg) and its position ahead of the body centre (m): ``CROWD_ROOM``
#: leaves the mount to the scenario's default, the LIMO's
CROWD_HFOV_DEG, CROWD_CAMERA_X = 90.0, LIMO.camera.position[0]
#: how far off the camera's axis (deg) a walker is placed while it must be seen: inside the view
#: with room for the person's width and the robot's swerves
_IN_VIEW_BEARING_DEG = 35.0


def _collision_course_angle(v_walker: float, v_robot: float, bearing_deg: float) -> float:
    """Angle φ (rad, from the robot's heading) of the direction a walker comes from, on a collision
    course with a robot driving straight at ``v_robot``, that keeps the walker at a constant
    ``bearing_deg`` from the robot (a collision course holds the bearing: the relative position is
    τ·(v_w·û + v_r·x̂) at τ seconds before the contact)."""
    tb = math.tan(math.radians(bearing_deg))
    lo, hi = 1e-3, math.pi - 1e-3  # bearing(φ) increases with φ
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if math.atan2(v_walker * math.sin(mid), v_walker * math.cos(mid) + v_robot) < math.atan(tb):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _walker(name: str, path: Sequence[Sequence[float]], waits: Sequence[float], speed: float) -> dict[str, Any]:
    pts = [[round(float(x), 4), round(float(y), 4)] for x, y in path]
    return {"class": "person", "name": name, "position": pts[0], "waypoints": pts,
            "waits": [round(float(w), 4) for w in waits], "speed": float(speed), "motion": "once"}


def crowd_case(kind: str, speed: float, seed: int, v_ref: float = CROWD_V_REF) -> dict[str, Any]:
    """One crowd scenario: ``{"name", "kind", "speed", "seed", "walkers": [spawn specs], "drive_s"}``.

    Times count from the drive's start (the walkers' spawn); the robot's nominal position is
    ``x0 + v_ref·t`` on y = 0. Kinds:

    * ``crossing`` — comes from ahead on one side and crosses the lane on a collision course (held
      at 35° off the camera's axis, so it is in view while it walks), then walks on to the other side;
    * ``head_on`` — walks straight at the robot along the lane, stops 1.3 m ahead of where the robot
      would be, stands, then steps 1.8 m aside;
    * ``overtaking`` — starts beside the robot, walks past it faster, cuts into the lane ahead, stands,
      then leaves the lane ahead;
    * ``stop_and_turn`` — walks into the lane from ahead on one side, stands, turns and walks back out.

    Seeds jitter sides, offsets and times; seeds ≥ 1 add a second person who passes on the other side
    of the lane, head-on, 1.4 m off it (several people at once)."""
    if kind not in CROWD_KINDS:
        raise ValueError(f"crowd kind {kind!r}: use one of {', '.join(CROWD_KINDS)}")
    if not 0 < speed <= 1.5 or v_ref <= 0:
        raise ValueError("walkers walk at up to 1.5 m/s; the reference must be positive")
    rng = np.random.default_rng([seed, CROWD_KINDS.index(kind), round(speed * 100)])
    x0 = CROWD_START[0]
    side = 1.0 if rng.uniform() < 0.5 else -1.0
    y_j = float(rng.uniform(-0.1, 0.1))

    def x_robot(t: float) -> float:
        return x0 + v_ref * t

    # time (s) for a robot at ``v_ref`` to close a ``gap`` (m) to a standing person ahead of its centre
    def reach(gap: float) -> float:
        return (gap - LIMO.length / 2 - 0.22) / v_ref  # the body's front, the person's radius

    walkers: list[dict[str, Any]] = []
    if kind == "crossing":
        t_c = 3.5 + float(rng.uniform(0.0, 1.0))
        walk = 2.0  # walks (in view) for 2 s before the conflict point, stands in view before that
        phi = _collision_course_angle(speed, v_ref, _IN_VIEW_BEARING_DEG)
        u = np.array([math.cos(phi), side * math.sin(phi)])
        p = np.array([x_robot(t_c), y_j])
        walkers.append(_walker("walker", [p + walk * speed * u, p - 2.5 * u], [t_c - walk, 0.0], speed))
        drive_s = 10.0
    elif kind == "head_on":
        wait0, stop_ahead = 1.0, 1.3
        sx = x0 + 5.0 + float(rng.uniform(0.0, 0.5))
        t_a = (sx - x0 - stop_ahead + speed * wait0) / (speed + v_ref)
        q = np.array([x_robot(t_a) + stop_ahead, y_j])
        dwell = reach(stop_ahead) + 0.5 + float(rng.uniform(0.0, 1.0))
        walkers.append(_walker("walker", [(sx, y_j), q, q + np.array([0.3, side * 1.8])], [wait0, dwell, 0.0], speed))
        drive_s = t_a + dwell + 5.0
    elif kind == "overtaking":
        lateral, cut_ahead = 1.0, 1.5  # cuts in once 1.5 m ahead of the camera
        start = np.array([x0 + 0.5, side * lateral])
        t_cut = (cut_ahead - 0.5 + CROWD_CAMERA_X) / (speed - v_ref) if speed > v_ref else 0.0
        cut = start + np.array([speed * t_cut, 0.0])
        q = np.array([cut[0] + lateral, y_j])  # a 45° cut into the lane
        t_a = t_cut + float(np.hypot(*(q - cut))) / speed
        dwell = reach(q[0] - x_robot(t_a)) + 0.5 + float(rng.uniform(0.0, 1.0))
        leave = q + np.array([2.5, side * 1.5])
        walkers.append(_walker("walker", [start, cut, q, leave], [0.0, 0.0, dwell, 0.0], speed))
        drive_s = t_a + dwell + 4.0
    else:  # stop_and_turn
        wait0 = 0.5
        q = np.array([x0 + 2.8 + float(rng.uniform(0.0, 0.4)), y_j])
        s = np.array([q[0] + 1.1, side * 1.6])
        t_a = wait0 + float(np.hypot(*(q - s))) / speed
        dwell = reach(q[0] - x_robot(t_a)) + 0.5 + float(rng.uniform(0.0, 1.0))
        walkers.append(_walker("walker", [s, q, s], [wait0, dwell, 0.0], speed))
        drive_s = t_a + dwell + 5.0
    if seed >= 1:
        y_p = -side * 1.4
        walkers.append(_walker("passer", [(x0 + 6.5, y_p), (x0 - 0.5, y_p)], [0.0, 0.0], speed))
    return {"name": f"{kind}_{speed:g}_s{seed}", "kind": kind, "speed": speed, "seed": seed, "walkers": walkers,
            "drive_s": round(float(min(max(drive_s, 8.0), 14.0)), 2), "v_ref": v_ref}


def crowd_cases(kinds: Sequence[str] = CROWD_KINDS, speeds: Sequence[float] = CROWD_SPEEDS,
                seeds: Sequence[int] = (0, 1, 2)) -> list[dict[str, Any]]:
    """The bench's default set: every kind × speed × seed (4 × 2 × 3 = 24)."""
    return [crowd_case(k, v, s) for s in seeds for k in kinds for v in speeds]


def crowd_nominal(case: dict[str, Any], dt: float = 0.02) -> dict[str, dict[str, float | None]]:
    """Per walker, on the nominal drive (the robot at ``v_ref`` straight ahead, nobody reacting): the
    time of the first contact (None: never) and how long the walker had been in the camera's view by
    then. What makes a case a conflict, and a fair one."""
    from .people import in_view, rectangle_gap, seen_before

    t = np.arange(0.0, case["drive_s"] + dt / 2, dt)
    xy = np.column_stack([CROWD_START[0] + case["v_ref"] * t, np.full(len(t), CROWD_START[1])])
    yaw = np.full(len(t), CROWD_START[2])
    out: dict[str, dict[str, float | None]] = {}
    for spec in case["walkers"]:
        obj = placed_object(spec)
        centres = np.array([obj.state_at(float(ti))[0][:2, 3] for ti in t])
        gap, _ = rectangle_gap(xy, yaw, centres, obj.footprint_radius)
        hit = np.flatnonzero(gap < 0)
        t_c = float(t[hit[0]]) if hit.size else None
        view = in_view(xy, yaw, centres, obj.footprint_radius, CROWD_HFOV_DEG, CROWD_CAMERA_X)
        out[spec["name"]] = {"contact_s": t_c, "in_view_before_s": None if t_c is None else
                             seen_before(t, view, t_c), "min_gap_m": float(gap.min())}
    return out
