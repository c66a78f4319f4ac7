"""CrowdNav-style families for ``riskfield bench crowd --mode core``: the filter core in closed loop.

No processes, no rendering: per episode a pure, seeded world (:func:`episode`) and a 50 Hz loop
(:func:`run_episode`) around one :class:`SafetyFilter` step, then the metrics from the recorded
tracks (:func:`episode_metrics`, which the unit tests call on hand-made tracks).

**The world.** The crowd bench's 12 × 6 m room (``scenarios.CROWD_ROOM``: walls at x = ±6, y = ±3),
a LIMO at ``START`` facing +x, static obstacles (walls and cabinets as axis-aligned boxes, tables
as cylinders) and people (upright cylinders of radius ``PERSON``) who walk piecewise-linear plans
with stops (the simulator's walker spec, ``motion: once``: :func:`plan_state` reads it the way
``simulator.scene.Motion`` does, so the same specs are valid ``sim/spawn`` requests:
``Episode.stack_case``). A person whose next step would touch the robot's body stands instead
(people are not pushed, and they do not push); one blocked for ``PATIENCE_S`` steps round the
robot on the side away from it (up to ``MAX_DETOURS`` times) and then walks on to the end of
their plan (without that, a yielding robot and a person who waits for it would wait for each
other forever).

**What the filter sees.** The ESDF it reads is rebuilt every ``MAP_PERIOD_S`` (10 Hz) from the
world as it was ``LATENCY_S`` (0.1 s) before, on 5 cm voxels in a planar window around the robot:
each obstacle inflated by its risk group's margin (people 0.15 m, ``high``; furniture 0.05 m,
``mid``; walls 0, ``low``), as the mapper does. The tracked objects are the people's true
positions and velocities of that same instant, the velocity plus N(0, σ) per axis (σ = 0.15 m/s,
the filter's ``object_speed_sigma``; the ``noise`` family draws σ in ``NOISE_SIGMA``, the tracker's
error measured by the stack's crowd bench: 0.09 m/s per axis from its median, 0.29 m/s RMS with
the lag at walkers' stops and turns), stamped with the map, ``age_ms`` 100, into
``motion.object_table`` (with the tracks' ``motion.TrackEvidence``) at every step. A person hidden
from the camera (the line of sight from ``CAMERA_X`` ahead of the body centre crosses a static obstacle) is in
neither: someone stepping out from behind a cabinet appears as a new, young track. There is no
field of view otherwise (people beside and behind the robot are known).

**The robot.** The operator's reference (forward speed ``v_ref``, no steering) is filtered every
step; the safe command reaches the platform ``COMMAND_DELAY_STEPS`` steps later (with the zero-
order hold of one period that is the filter's assumed 0.06 s, ``MotionParams.command_delay_s``),
whose speed and yaw rate follow it within the LIMO's acceleration limits (1.5 m/s², 6 rad/s²,
``protocol.platforms.LIMO``: the simulator's first-order actuator), and the state is integrated
exactly with the filter's own model (``model.integrate``) for the actual twist.

**Metrics** (per episode; ``people`` defines contacts): at-fault contacts (the LIMO rectangle
overlapping a person while its nearest point moves towards them faster than 0.05 m/s) and the
person's contacts; static contacts (any overlap of the rectangle with a wall or furniture);
idle displacement (path length travelled while the reference was zero); blind reverse (travel
against the heading the operator did not ask for while the floor behind the body was not seen
free: the camera, ``CAMERA_HFOV_DEG`` wide from ``CAMERA_X`` ahead of the body centre, marks the
floor its rays cross up to ``SEEN_RANGE`` or the first static obstacle at every map, and a cell
stays seen free for the mapper's ``observed_free_s``, as ``mapping.free_floor`` keeps it); the
minimum body gap to people; success (the body centre past the goal within the
time limit, for the families with a goal) and the time to goal; time stopped (robot speed below
``FREEZE_SPEED`` while the reference is positive).

**Evasion** (``--evade``: the filter's opt-in ``evade``) reads that seen floor, less the cells of
the static obstacles and the people shown, as the mapper's ``EsdfGrid.observed_free``, through the
supervisor's own ``Evader.step``.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from riskfield.experiments import people as P
from riskfield.protocol import RiskConfig, TrackedObject, ade20k
from riskfield.protocol.platforms import LIMO
from riskfield.services.fields import EsdfField
from riskfield.services.mapping.config import FloorParams
from riskfield.services.safety_filter.config import LIMO_LENGTH, LIMO_WIDTH, FilterConfig
from riskfield.services.safety_filter.evade import Evader, FreeFloor
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.motion import TrackEvidence, object_table
from riskfield.services.safety_filter.state import FilterState

FAMILIES = ("idle_passing", "walls_beside", "wall_behind", "emerging", "runners", "groups", "noise")
#: the crowd bench's start pose (``scenarios.CROWD_START``) and room half sizes (``CROWD_ROOM``)
START = (-4.5, 0.0, 0.0)
ROOM_HALF = (6.0, 3.0)
PERSON = 0.22  # the simulator's person (radius, m)
HX, HY = LIMO_LENGTH / 2, LIMO_WIDTH / 2
GROUPS = ["high", "mid", "low"]
HIGH, MID, LOW = 1, 2, 3
RATE_HZ = 50.0
MAP_PERIOD_S = 0.1
LATENCY_S = 0.1
VOXEL = 0.05
WINDOW = 2.0  # half size (m) of the ESDF window around the robot
MAX_DISTANCE = 2.0
CAMERA_X = 0.15
COMMAND_DELAY_STEPS = 2
TRACKER_SIGMA = 0.15
#: m/s: the noise family's σ range, the tracker's velocity error per axis measured by
#: ``riskfield bench crowd --variants motion --seeds 0,1`` (people.tracker_errors): robust σ to RMS
NOISE_SIGMA = (0.09, 0.29)
PATIENCE_S = 1.0
MAX_DETOURS = 3
FREEZE_SPEED = 0.02
CAMERA_HFOV_DEG = 90.0  # the crowd bench's camera (scenarios.CROWD_HFOV_DEG)
SEEN_RANGE = 4.0
SEEN_RAYS = 91
#: the families' targets (``summarise``: which episodes miss them)
SUCCESS_TARGET = 0.95
RESULTS_BEGIN, RESULTS_END = "<!-- crowd-core:begin -->", "<!-- crowd-core:end -->"


# -- the world ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Static:
    """A static obstacle: an axis-aligned box (``lo``/``hi`` floor corners) or a cylinder
    (``centre``, ``radius``), of an ADE20K class (its risk group from ``RiskConfig``)."""

    name: str
    cls: str
    lo: tuple[float, float] | None = None
    hi: tuple[float, float] | None = None
    centre: tuple[float, float] | None = None
    radius: float = 0.0
    height: float = 1.0

    @property
    def label(self) -> int:
        return ade20k.index(self.cls)

    def distance(self, xy: np.ndarray) -> np.ndarray:
        """Signed planar distance (m) from points (N, 2) to the obstacle."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        if self.centre is not None:
            return np.hypot(xy[:, 0] - self.centre[0], xy[:, 1] - self.centre[1]) - self.radius
        c = 0.5 * (np.array(self.lo) + np.array(self.hi))
        half = 0.5 * (np.array(self.hi) - np.array(self.lo))
        q = np.abs(xy - c) - half
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)

    def spec(self) -> dict[str, Any]:
        """What ``sim/spawn`` places for it (``simulator.scenario.ObjectSpec``)."""
        if self.centre is not None:
            return {"class": self.cls, "name": self.name, "position": [self.centre[0], self.centre[1]],
                    "size": [2 * self.radius, 2 * self.radius, self.height], "shape": "cylinder"}
        c = 0.5 * (np.array(self.lo) + np.array(self.hi))
        s = np.array(self.hi) - np.array(self.lo)
        return {"class": self.cls, "name": self.name, "position": [float(c[0]), float(c[1])],
                "size": [float(s[0]), float(s[1]), self.height], "shape": "box"}


def box(name: str, cls: str, x0: float, y0: float, x1: float, y1: float) -> Static:
    return Static(name, cls, (min(x0, x1), min(y0, y1)), (max(x0, x1), max(y0, y1)))


def room_walls() -> list[Static]:
    """The room's four walls, 0.2 m thick, outside the 12 × 6 m floor."""
    X, Y = ROOM_HALF
    return [box("room_n", "wall", -X - 0.2, Y, X + 0.2, Y + 0.2),
            box("room_s", "wall", -X - 0.2, -Y - 0.2, X + 0.2, -Y),
            box("room_e", "wall", X, -Y, X + 0.2, Y), box("room_w", "wall", -X - 0.2, -Y, -X, Y)]


def walker(name: str, path: Sequence[Sequence[float]], waits: Sequence[float], speed: float) -> dict[str, Any]:
    """A person's plan as the simulator's walker spec (``sim/spawn``; ``motion: once``)."""
    pts = [[round(float(x), 4), round(float(y), 4)] for x, y in path]
    return {"class": "person", "name": name, "position": pts[0], "waypoints": pts,
            "waits": [round(float(w), 4) for w in waits], "speed": round(float(speed), 4), "motion": "once"}


def plan_state(spec: dict[str, Any], elapsed: float) -> tuple[np.ndarray, np.ndarray]:
    """(position, velocity) of a walker spec ``elapsed`` s after it started: stand ``waits[i]`` at
    waypoint i, walk to the next at ``speed``, stay at the last (``simulator.scene.Motion``, ``once``)."""
    pts = np.asarray(spec["waypoints"], float)
    waits, speed = spec.get("waits") or [0.0] * len(pts), float(spec["speed"])
    s = max(0.0, elapsed)
    for i in range(len(pts) - 1):
        if s < waits[i]:
            return pts[i].copy(), np.zeros(2)
        s -= waits[i]
        leg = pts[i + 1] - pts[i]
        length = float(np.hypot(*leg))
        dur = length / speed if speed > 0 else (math.inf if length > 0 else 0.0)
        if s < dur:
            d = leg / length
            return pts[i] + d * speed * s, d * speed
        s -= dur
    return pts[-1].copy(), np.zeros(2)


@dataclass
class Episode:
    """One seeded episode of a family: the world, the operator's reference and the goal."""

    family: str
    seed: int
    v_ref: float
    duration_s: float
    goal_x: float | None
    sigma: float
    statics: list[Static]
    walkers: list[dict[str, Any]]
    params: dict[str, Any] = field(default_factory=dict)

    def stack_case(self) -> dict[str, Any]:
        """The episode as a case of the full-stack mode (``benches.crowd.run_case``): the same walker
        specs, the static obstacles spawned before the drive (room walls are the simulator's own)."""
        speed = max((w["speed"] for w in self.walkers), default=0.0)
        return {"name": f"{self.family}_s{self.seed}", "kind": self.family, "speed": speed, "seed": self.seed,
                "walkers": [dict(w) for w in self.walkers],
                "statics": [s.spec() for s in self.statics if not s.name.startswith("room_")],
                "drive_s": round(self.duration_s, 2), "v_ref": self.v_ref}


def _extent(phi: float) -> float:
    """Distance from the body centre to the rectangle's edge along the body-frame direction phi."""
    c, s = abs(math.cos(phi)), abs(math.sin(phi))
    return min(HX / c if c > 1e-9 else math.inf, HY / s if s > 1e-9 else math.inf)


def _unit(a: float) -> np.ndarray:
    return np.array([math.cos(a), math.sin(a)])


def _x_robot(v: float, t: float) -> float:
    return START[0] + v * t


def _crossing(rng: np.random.Generator, name: str, v_ref: float, speed: float, t_c: float,
              side: float) -> dict[str, Any]:
    """A walker at constant ``speed`` who meets the nominal robot's front at ``t_c``, crossing from
    ``side`` (+1: from +y) at 60-120° to the path, from and to 2.6 m off the lane."""
    phi = math.radians(float(rng.uniform(60.0, 120.0)))
    w = speed * np.array([math.cos(phi), -side * math.sin(phi)])
    p = np.array([_x_robot(v_ref, t_c) + HX + PERSON * float(rng.uniform(0.3, 0.9)), float(rng.uniform(-0.1, 0.1))])
    t_half = 2.6 / (speed * math.sin(phi))
    start, end = p - w * t_half, p + w * t_half
    t0 = t_c - t_half
    if t0 < 0:  # started mid-way: from where they would have been at t = 0
        start, t0 = p - w * t_c, 0.0
    return walker(name, [start, end], [t0, 0.0], speed)


def _head_on(rng: np.random.Generator, name: str, v_ref: float, speed: float, away: float,
             through: bool) -> tuple[dict[str, Any], float]:
    """Walks down the lane at the robot; stops ~1-1.5 m before it and steps aside towards ``away``
    after a dwell, or (``through``) walks on (and is blocked by the robot). Returns (spec, dwell)."""
    sx = START[0] + float(rng.uniform(5.0, 7.0))
    y = float(rng.uniform(-0.12, 0.12))
    wait0 = float(rng.uniform(0.0, 1.5))
    if through:
        return walker(name, [(sx, y), (START[0] - 1.0, y)], [wait0, 0.0], speed), 0.0
    ahead = float(rng.uniform(1.0, 1.5))
    t_a = (sx - START[0] - ahead + speed * wait0) / (speed + v_ref)
    q = np.array([_x_robot(v_ref, t_a) + ahead, y])
    dwell = float(rng.uniform(1.0, 3.0))
    return walker(name, [(sx, y), q, q + np.array([0.3, away * 1.6])], [wait0, dwell, 0.0], speed), dwell


def episode(family: str, seed: int) -> Episode:
    """The episode ``seed`` of ``family`` (pure: the same arguments give the same episode)."""
    if family not in FAMILIES:
        raise ValueError(f"crowd family {family!r}: use one of {', '.join(FAMILIES)}")
    rng = np.random.default_rng([seed, FAMILIES.index(family), 32])
    statics = room_walls()
    walkers: list[dict[str, Any]] = []
    params: dict[str, Any] = {}
    sigma, goal, v_ref = TRACKER_SIGMA, None, 0.5
    x0 = START[0]
    dwell = 0.0
    length = 7.0
    if family == "idle_passing":
        v_ref, duration = 0.0, 12.0
        kinds = []
        for k in range(int(rng.integers(1, 4))):
            kind = str(rng.choice(["passing", "approaching", "standing"]))
            kinds.append(kind)
            speed = float(rng.uniform(0.6, 1.5))
            phi = float(rng.uniform(-math.pi, math.pi))
            gap = float(rng.uniform(0.2, 1.0))
            if kind == "passing":  # straight past the robot, never towards it
                d = _unit(float(rng.uniform(-math.pi, math.pi)))
                n = np.array([-d[1], d[0]]) * (1.0 if rng.uniform() < 0.5 else -1.0)
                c = np.array(START[:2]) + n * (math.hypot(HX, HY) + PERSON + gap)
                walkers.append(walker(f"p{k}", [c - 4.0 * d, c + 4.0 * d], [float(rng.uniform(0, 3)), 0.0], speed))
            elif kind == "approaching":  # walks up to it (or into it), stands, walks off sideways
                gap = float(rng.uniform(-0.05, 0.5))
                u = _unit(phi)
                stop = np.array(START[:2]) + u * (_extent(phi) + PERSON + gap)
                far = stop + u * float(rng.uniform(2.5, 3.5))
                off = stop + np.array([-u[1], u[0]]) * 2.5 * (1.0 if rng.uniform() < 0.5 else -1.0)
                walkers.append(walker(f"p{k}", [far, stop, off], [float(rng.uniform(0, 2)),
                                                                   float(rng.uniform(1, 4)), 0.0], speed))
            else:  # stands near it all along
                c = np.array(START[:2]) + _unit(phi) * (_extent(phi) + PERSON + float(rng.uniform(0.15, 0.8)))
                walkers.append(walker(f"p{k}", [c, c], [duration, 0.0], 0.5))
        params["kinds"] = kinds
    elif family == "walls_beside":
        side = 1.0 if rng.uniform() < 0.5 else -1.0
        w = float(rng.uniform(0.45, 0.6))
        statics.append(box("wall_beside", "wall", x0 - 1.0, side * w, x0 + length + 1.5, side * (w + 0.1)))
        speed = float(rng.uniform(0.8, 1.5))
        through = bool(rng.uniform() < 0.5)
        spec, dwell = _head_on(rng, "head_on", v_ref, speed, -side, through)
        walkers.append(spec)
        params.update(wall_gap_m=round(w, 3), side=side, head_on_through=through)
        if rng.uniform() < 0.5:  # a second one from the open side, into the lane, stands, turns back
            t_c = float(rng.uniform(3.0, 9.0))
            sp = float(rng.uniform(0.8, 1.5))
            q = np.array([_x_robot(v_ref, t_c) + float(rng.uniform(1.0, 1.6)), side * max(w - PERSON - 0.05, 0.0)])
            start = q + np.array([0.8, -side * 2.4])
            t_walk = float(np.hypot(*(q - start))) / sp
            d2 = float(rng.uniform(1.0, 2.5))
            walkers.append(walker("crosser", [start, q, start], [max(t_c - 1.0 - t_walk, 0.0), d2, 0.0], sp))
            dwell += d2
        goal = x0 + length
    elif family == "wall_behind":
        gb = float(rng.uniform(0.3, 0.4))
        statics.append(box("wall_behind", "wall", x0 - HX - gb - 0.1, -2.0, x0 - HX - gb, 2.0))
        slow = bool(rng.uniform() < 0.5)
        v_ref = float(rng.uniform(0.1, 0.25)) if slow else 0.0
        length = 1.5
        speed = float(rng.uniform(0.6, 1.3))
        gap = float(rng.uniform(-0.05, 0.5))
        wait0 = float(rng.uniform(0.0, 2.0))
        phi = math.radians(float(rng.uniform(-30.0, 30.0)))
        far = np.array([x0, 0.0]) + 3.5 * _unit(phi)
        t_a = wait0 + (3.5 - _extent(phi) - PERSON - gap) / speed
        stand = np.array([_x_robot(v_ref, t_a), 0.0]) + _unit(phi) * (_extent(phi) + PERSON + gap)
        dwell = float(rng.uniform(2.0, 5.0))
        off = stand + np.array([0.4, 2.2 * (1.0 if rng.uniform() < 0.5 else -1.0)])
        walkers.append(walker("walker", [far, stand, off], [wait0, dwell, 0.0], speed))
        params.update(wall_gap_m=round(gb, 3), slow=slow, stand_gap_m=round(gap, 3))
        goal = x0 + length if slow else None
        duration = 12.0 if not slow else length / v_ref + dwell + wait0 + 8.0
    elif family == "emerging":
        length = 6.0
        side = 1.0 if rng.uniform() < 0.5 else -1.0
        c = float(rng.uniform(0.45, 0.8))  # lane centre to the furniture's near face
        xf = x0 + float(rng.uniform(2.0, 4.0))
        if rng.uniform() < 0.6:
            sx, sy = float(rng.uniform(0.5, 1.0)), float(rng.uniform(0.4, 0.8))
            furn = box("cabinet", "cabinet", xf - sx / 2, side * c, xf + sx / 2, side * (c + sy))
            hide = np.array([xf + sx / 2 + PERSON + 0.05, side * (c + sy / 2)])
        else:
            r = float(rng.uniform(0.3, 0.5))
            furn = Static("table", "table", centre=(xf, side * (c + r)), radius=r, height=0.75)
            hide = np.array([xf + r + PERSON + 0.05, side * (c + r)])
        statics.append(furn)
        speed = float(rng.uniform(0.8, 1.5))
        target = np.array([hide[0] - float(rng.uniform(0.0, 0.6)), -side * 2.2])
        lead = float(rng.uniform(1.0, 2.0))
        t_w, got = _emerging_start(statics, hide, target, speed, v_ref, lead)
        walkers.append(walker("emerger", [hide, target], [t_w, 0.0], speed))
        params.update(furniture=furn.cls, lane_gap_m=round(c, 3), lead_s=round(lead, 2),
                      lead_achieved_s=None if got is None else round(got, 2))
        goal = x0 + length
    elif family == "runners":
        n = 1 if rng.uniform() < 0.6 else 2
        side = 1.0 if rng.uniform() < 0.5 else -1.0
        t_c = float(rng.uniform(3.0, 8.0))
        speeds = []
        for k in range(n):
            sp = float(rng.uniform(1.8, 2.5))
            speeds.append(round(sp, 2))
            walkers.append(_crossing(rng, f"runner{k}", v_ref, sp, t_c, side))
            side, t_c = -side, t_c + float(rng.uniform(1.0, 3.0))
        params["speeds"] = speeds
        goal = x0 + length
    elif family == "groups":
        n = int(rng.integers(2, 5))
        kinds = []
        for k in range(n):
            kind = str(rng.choice(["crossing", "head_on", "overtaking", "standing_in_lane", "passing"]))
            kinds.append(kind)
            sp = float(rng.uniform(0.6, 1.5))
            side = 1.0 if rng.uniform() < 0.5 else -1.0
            if kind == "crossing":
                walkers.append(_crossing(rng, f"p{k}", v_ref, sp, float(rng.uniform(2.0, 10.0)), side))
            elif kind == "head_on":
                spec, d = _head_on(rng, f"p{k}", v_ref, sp, side, bool(rng.uniform() < 0.3))
                walkers.append(spec)
                dwell += d
            elif kind == "overtaking":
                sp = float(rng.uniform(0.9, 1.5))
                start = np.array([x0 - 0.5, side * 1.0])
                cut = start + np.array([float(rng.uniform(2.5, 4.0)), 0.0])
                q = np.array([cut[0] + 1.0, float(rng.uniform(-0.1, 0.1))])
                d = float(rng.uniform(0.5, 2.0))
                walkers.append(walker(f"p{k}", [start, cut, q, q + np.array([2.5, side * 1.5])],
                                      [float(rng.uniform(0.0, 1.0)), 0.0, d, 0.0], sp))
                dwell += d
            elif kind == "standing_in_lane":
                q = np.array([x0 + float(rng.uniform(1.5, 6.0)), float(rng.uniform(-0.15, 0.15))])
                d = float(rng.uniform(2.0, 8.0))
                walkers.append(walker(f"p{k}", [q, q + np.array([0.0, side * 1.8])], [d, 0.0], sp))
                dwell += d
            else:
                y = side * float(rng.uniform(0.75, 1.4))
                sx = x0 + float(rng.uniform(5.0, 8.0))
                walkers.append(walker(f"p{k}", [(sx, y), (x0 - 1.5, y)], [float(rng.uniform(0, 3)), 0.0], sp))
        params["kinds"] = kinds
        goal = x0 + length
    else:  # noise
        sigma = float(rng.uniform(*NOISE_SIGMA))
        kinds = []
        for k in range(int(rng.integers(2, 5))):
            side = 1.0 if rng.uniform() < 0.5 else -1.0
            x = x0 + float(rng.uniform(1.0, 6.5))
            if rng.uniform() < 0.25:  # standing in the lane, then leaving
                d = float(rng.uniform(1.0, 4.0))
                q = np.array([x, float(rng.uniform(-0.1, 0.1))])
                walkers.append(walker(f"p{k}", [q, q + np.array([0.0, side * 1.8])], [d, 0.0], 0.8))
                dwell += d
                kinds.append("in_lane")
            else:
                q = np.array([x, side * (HY + PERSON + float(rng.uniform(0.25, 0.8)))])
                walkers.append(walker(f"p{k}", [q, q], [60.0, 0.0], 0.5))
                kinds.append("beside")
        params.update(sigma=round(sigma, 3), kinds=kinds)
        goal = x0 + length
    if family in ("walls_beside", "emerging", "runners", "groups", "noise"):
        duration = length / v_ref + dwell + 8.0
    return Episode(family, seed, v_ref, float(duration), goal, sigma, statics, walkers, params)


def _emerging_start(statics: list[Static], hide: np.ndarray, target: np.ndarray, speed: float, v_ref: float,
                    lead: float) -> tuple[float, float | None]:
    """The start time of the emerger's walk for which the nominal robot (straight on at ``v_ref``)
    would touch them about ``lead`` s after its camera first sees them walking; (t, lead achieved).
    Walking, not standing: someone who stands in view beside the path is on no collision course,
    so the lead a filter has is the time from the first sight of the step out."""
    t = np.arange(0.0, 16.0, 0.04)
    xy = np.column_stack([START[0] + v_ref * t, np.zeros_like(t)])
    d = target - hide
    dist = float(np.hypot(*d))
    best, best_err, got = 0.0, math.inf, None
    for t_w in np.arange(0.0, 10.0, 0.1):
        s = np.clip((t - t_w) * speed, 0.0, dist)
        c = hide + np.outer(s / dist, d)
        gap, _ = P.rectangle_gap(xy, np.zeros_like(t), c, PERSON)
        hit = np.flatnonzero(gap < 0)
        if not hit.size:
            continue
        cam = xy + np.array([CAMERA_X, 0.0])
        seen = visible(cam, c, statics)
        first = np.flatnonzero(seen & (t >= t_w))
        if not first.size:
            continue
        ahead = float(t[hit[0]] - t[first[0]])
        if abs(ahead - lead) < best_err:
            best, best_err, got = float(t_w), abs(ahead - lead), ahead
    return best, got


def visible(cam: np.ndarray, centre: np.ndarray, statics: Sequence[Static]) -> np.ndarray:
    """Per row: the segment from the camera to the person's centre crosses no static obstacle
    (sampled every 5 cm; a person's centre is at least their radius from any obstacle)."""
    cam, centre = np.atleast_2d(cam), np.atleast_2d(centre)
    length = float(np.max(np.hypot(*(centre - cam).T))) if len(cam) else 0.0
    k = max(2, int(length / 0.05) + 1)
    s = np.linspace(0.0, 1.0, k)[None, :, None]
    pts = (cam[:, None, :] + s * (centre - cam)[:, None, :]).reshape(-1, 2)
    out = np.ones(len(cam), bool)
    for st in statics:
        if st.name.startswith("room_"):
            continue
        out &= ~(st.distance(pts).reshape(len(cam), k) < 0).any(axis=1)
    return out


# -- geometry of contacts ----------------------------------------------------------------------------

def rectangle_corners(xy: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 4, 2) world corners of the LIMO rectangle."""
    loc = np.array([[HX, HY], [-HX, HY], [-HX, -HY], [HX, -HY]])
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    return np.stack([xy[:, None, 0] + c * loc[:, 0] - s * loc[:, 1], xy[:, None, 1] + s * loc[:, 0] + c * loc[:, 1]],
                    axis=-1)


def static_gap(xy: np.ndarray, yaw: np.ndarray, st: Static) -> np.ndarray:
    """Signed planar distance (m, < 0: overlap) from the LIMO rectangle to a static obstacle.

    Cylinder: ``people.rectangle_gap``. Box: two convex polygons; apart, their distance is the
    smallest of a corner of one to the other; overlapping (a separating-axis test on the four
    edge normals finds no gap), minus the smallest overlap along those normals."""
    xy, yaw = np.atleast_2d(np.asarray(xy, float)), np.atleast_1d(np.asarray(yaw, float))
    if st.centre is not None:
        return P.rectangle_gap(xy, yaw, np.broadcast_to(np.array(st.centre), xy.shape), st.radius)[0]
    corners = rectangle_corners(xy, yaw)  # (N, 4, 2)
    lo, hi = np.array(st.lo), np.array(st.hi)
    bc = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    d_rc = st.distance(corners.reshape(-1, 2)).reshape(-1, 4).min(axis=1)
    d_bc = np.min([P.rectangle_gap(xy, yaw, np.broadcast_to(b, xy.shape), 0.0)[0] for b in bc], axis=0)
    apart = np.minimum(d_rc, d_bc)
    overlap = np.full(len(xy), np.inf)
    axes = [np.broadcast_to([1.0, 0.0], xy.shape), np.broadcast_to([0.0, 1.0], xy.shape),
            np.column_stack([np.cos(yaw), np.sin(yaw)]), np.column_stack([-np.sin(yaw), np.cos(yaw)])]
    for ax in axes:
        pr = np.einsum("nkd,nd->nk", corners, ax)
        pb = bc @ ax.T  # (4, N)
        o = np.minimum(pr.max(axis=1), pb.max(axis=0)) - np.maximum(pr.min(axis=1), pb.min(axis=0))
        overlap = np.minimum(overlap, o)
    return np.where(overlap > 0, -overlap, np.maximum(apart, 0.0))


# -- the closed loop ---------------------------------------------------------------------------------

@dataclass
class Trace:
    """What one episode recorded, one row per control step (after the step)."""

    t: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    velocity: np.ndarray  # world (N, 2)
    omega: np.ndarray
    v_ref: np.ndarray  # the operator's forward speed at the step
    w_ref: np.ndarray
    u: np.ndarray  # (N, 2) the filter's command
    people: np.ndarray  # (N, P, 2)
    yielding: np.ndarray
    object_rows: np.ndarray
    fallbacks: dict[str, int]
    start_xy: np.ndarray
    start_yaw: float
    wall_s: float = 0.0
    seen_behind: np.ndarray | None = None  # the floor behind the body was seen free (None: never)
    evading: np.ndarray | None = None


class _Person:
    """A walker following its plan on its own clock, which stops while the robot blocks it."""

    def __init__(self, spec: dict[str, Any]):
        self.spec, self.clock, self.blocked = spec, 0.0, 0.0
        self.xy, self.v = plan_state(spec, 0.0)
        self.detours = 0

    def step(self, dt: float, body_gap: Any, statics: Sequence[Static], robot_xy: np.ndarray) -> None:
        nxt, v = plan_state(self.spec, self.clock + dt)
        g_now, g_next = body_gap(self.xy), body_gap(nxt)
        if g_next < 0.0 and g_next < g_now:
            self.v = np.zeros(2)
            self.blocked += dt
            if self.blocked >= PATIENCE_S and self.detours < MAX_DETOURS:
                self._detour(v, statics, robot_xy)
            return
        self.blocked = 0.0
        self.clock += dt
        self.xy, self.v = nxt, v

    def _detour(self, v: np.ndarray, statics: Sequence[Static], robot_xy: np.ndarray) -> None:
        """Round the robot on the side away from its centre (or the other, if a wall is there),
        then on to the end of the plan."""
        speed = float(self.spec["speed"]) or 0.8
        d = v / max(float(np.hypot(*v)), 1e-9) if np.any(v) else _unit(0.0)
        n = np.array([-d[1], d[0]])
        if float(n @ (self.xy - robot_xy)) < 0:
            n = -n
        for side in (n, -n):
            a = self.xy + side * 0.75
            b = a + d * 1.2
            if all(float(s.distance(np.array([a, b])).min()) > PERSON + 0.02 for s in statics):
                end = np.asarray(self.spec["waypoints"][-1], float)
                self.spec = walker(self.spec["name"], [self.xy, a, b, end], [0.0, 0.0, 0.0, 0.0], speed)
                self.clock, self.blocked = 0.0, 0.0
                self.detours += 1
                return
        self.detours = MAX_DETOURS  # boxed in: keeps waiting


def _static_grid(statics: Sequence[Static], risk: RiskConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origin (2,), distance (nx, ny), group (nx, ny)) of the static obstacles over the room plus
    the window, each inflated by its group's margin."""
    lut, margins = risk.label_to_group(), risk.margins()
    lo = np.array([-ROOM_HALF[0] - WINDOW - 0.5, -ROOM_HALF[1] - WINDOW - 0.5])
    n = np.floor(2 * (np.array(ROOM_HALF) + WINDOW + 0.5) / VOXEL + 1e-9).astype(int) + 1
    gx, gy = np.meshgrid(lo[0] + VOXEL * np.arange(n[0]), lo[1] + VOXEL * np.arange(n[1]), indexing="ij")
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    dist = np.full(len(pts), MAX_DISTANCE)
    group = np.zeros(len(pts), np.uint8)
    for st in statics:
        g = int(lut[st.label])
        d = st.distance(pts) - margins[g]
        nearer = d < dist
        dist[nearer], group[nearer] = d[nearer], g
    return lo, dist.reshape(n), group.reshape(n)


def _window_field(grid: tuple[np.ndarray, np.ndarray, np.ndarray], centre: np.ndarray,
                  people: Sequence[np.ndarray], risk: RiskConfig) -> EsdfField:
    """The ESDF the filter reads: the window about ``centre``, with the (inflated) people."""
    lo, dist, group = grid
    i0 = np.floor((centre - WINDOW - lo) / VOXEL).astype(int)
    i0 = np.clip(i0, 0, np.array(dist.shape) - 1)
    k = round(2 * WINDOW / VOXEL) + 1
    i1 = np.minimum(i0 + k, np.array(dist.shape))
    d = dist[i0[0]:i1[0], i0[1]:i1[1]].copy()
    g = group[i0[0]:i1[0], i0[1]:i1[1]].copy()
    origin = lo + VOXEL * i0
    if len(people):
        gx = origin[0] + VOXEL * np.arange(d.shape[0])
        gy = origin[1] + VOXEL * np.arange(d.shape[1])
        reach = PERSON + float(risk.margins()[HIGH])
        for c in people:
            dp = np.hypot(gx[:, None] - c[0], gy[None, :] - c[1]) - reach
            nearer = dp < d
            d[nearer], g[nearer] = dp[nearer], HIGH
    d = np.clip(d, -MAX_DISTANCE, MAX_DISTANCE).astype(np.float32)[:, :, None]
    return EsdfField(d, (origin[0], origin[1], 0.0), VOXEL, g[:, :, None], GROUPS, MAX_DISTANCE)


def _mark_seen(seen: np.ndarray, grid: tuple[np.ndarray, np.ndarray, np.ndarray], cam: np.ndarray, yaw: float,
               t: float) -> None:
    """The camera's rays across the floor, to ``SEEN_RANGE`` or the first static obstacle: seen at t."""
    lo, dist, _ = grid
    half = math.radians(CAMERA_HFOV_DEG) / 2
    a = yaw + np.linspace(-half, half, SEEN_RAYS)
    r = np.arange(0.0, SEEN_RANGE, VOXEL / 2)
    pts = cam[None, None, :] + r[None, :, None] * np.stack([np.cos(a), np.sin(a)], -1)[:, None, :]
    ij = np.floor((pts - lo) / VOXEL + 0.5).astype(int)
    ij = np.clip(ij, 0, np.array(dist.shape) - 1)
    blocked = np.cumsum(dist[ij[..., 0], ij[..., 1]] < 0, axis=1) > 0
    hit = ij[~blocked]
    seen[hit[:, 0], hit[:, 1]] = t


def _free_floor(seen: np.ndarray, grid: tuple[np.ndarray, np.ndarray, np.ndarray], people: Sequence[np.ndarray],
                t: float, window_s: float) -> FreeFloor:
    """What the mapper would publish as ``observed_free``: seen within the window, no obstacle now."""
    lo, dist, _ = grid
    free = (t - seen <= window_s) & (dist > 0)
    if len(people):
        gx, gy = lo[0] + VOXEL * np.arange(dist.shape[0]), lo[1] + VOXEL * np.arange(dist.shape[1])
        for c in people:
            free &= np.hypot(gx[:, None] - c[0], gy[None, :] - c[1]) > PERSON
    return FreeFloor(lo.copy(), VOXEL, free)


def _behind(xy: np.ndarray, yaw: float) -> np.ndarray:
    """The rear edge of the body (corners and middle)."""
    c, s_ = math.cos(yaw), math.sin(yaw)
    local = np.array([[-HX, -HY], [-HX, 0.0], [-HX, HY]])
    return xy + local @ np.array([[c, s_], [-s_, c]])


def _towards(v: float, target: float, rate: float, dt: float) -> float:
    step = rate * dt
    return v + min(max(target - v, -step), step)


def run_episode(ep: Episode, filt: SafetyFilter | None = None, accel_limits: bool = True,
                delay_steps: int = COMMAND_DELAY_STEPS, max_s: float | None = None) -> Trace:
    """The closed loop of one episode (module docstring). Ends at the time limit, or 0.5 s after
    the goal. ``max_s`` cuts it short (the tests)."""
    wall0 = time.perf_counter()
    filt = filt or SafetyFilter(FilterConfig())
    cfg, model = filt.config, filt.model
    evader = Evader(model, cfg, filt.delta) if cfg.evade else None
    gains = filt.gains.for_groups(GROUPS)
    window_s = FloorParams().observed_free_s
    dt = 1.0 / RATE_HZ
    risk = RiskConfig()
    rng = np.random.default_rng([ep.seed, FAMILIES.index(ep.family), 99])
    grid = _static_grid(ep.statics, risk)
    floor_seen = np.full(grid[1].shape, -math.inf)
    floor: FreeFloor | None = None
    per_map, lag = round(MAP_PERIOD_S * RATE_HZ), round(LATENCY_S * RATE_HZ)
    s = FilterState.planar(*START)
    people = [_Person(dict(w)) for w in ep.walkers]
    first_seen: list[float | None] = [None] * len(people)
    history: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (robot xy, yaw), people xy, v
    queue = [np.zeros(2)] * delay_steps
    v_act = w_act = 0.0
    steps = round(min(ep.duration_s, max_s or math.inf) * RATE_HZ)
    rec: dict[str, list[Any]] = {k: [] for k in ("t", "xy", "yaw", "vel", "om", "vr", "wr", "u", "pp", "y", "o",
                                                  "sb", "ev")}
    fallbacks: dict[str, int] = {}
    field_ = None
    msgs: list[TrackedObject] = []
    evidence = TrackEvidence(cfg.object_evidence)
    stamp = 0
    goal_at = None
    u_ref = np.array([ep.v_ref, 0.0])
    for k in range(steps):
        t = k * dt
        pose = np.array([s.position[0], s.position[1], s.yaw])
        history.append((pose, np.array([p.xy for p in people]).reshape(-1, 2),
                        np.array([p.v for p in people]).reshape(-1, 2)))
        if k % per_map == 0:
            then_pose, then_xy, then_v = history[max(0, len(history) - 1 - lag)]
            t_obs = max(0.0, t - LATENCY_S)
            cam = then_pose[:2] + CAMERA_X * _unit(then_pose[2])
            seen = visible(np.repeat(cam[None], len(people), 0), then_xy, ep.statics) if people else np.zeros(0, bool)
            shown = [then_xy[i] for i in range(len(people)) if seen[i]]
            field_ = _window_field(grid, s.position[:2], shown, risk)
            _mark_seen(floor_seen, grid, cam, float(then_pose[2]), t_obs)
            floor = _free_floor(floor_seen, grid, shown, t_obs, window_s)
            msgs = []
            for i in range(len(people)):
                if not seen[i]:
                    first_seen[i] = None
                    continue
                if first_seen[i] is None:
                    first_seen[i] = t_obs
                noisy = then_v[i] + rng.normal(0.0, ep.sigma, 2)
                msgs.append(TrackedObject(id=i, label=ade20k.index("person"), risk_group=HIGH,
                                          position=(*then_xy[i], 0.0), velocity=(*noisy, 0.0), radius=PERSON,
                                          age_ms=LATENCY_S * 1e3, tracked_ms=(t_obs - first_seen[i]) * 1e3))
            stamp = round(t * 1e9)
            evidence.observe(msgs, stamp)
        table = object_table(msgs, cfg, round(t * 1e9), stamp, near=s.position, evidence=evidence)
        res = filt.filter(s, u_ref, field_, None, table)
        if res.fallback is not None:
            fallbacks[res.fallback] = fallbacks.get(res.fallback, 0) + 1
        u = np.asarray(res.u, float).copy()
        retreat = None if evader is None else evader.step(s, res.yielding, not u_ref.any(), table, gains, field_, floor)
        queue.append(u if retreat is None else retreat)
        cmd = queue.pop(0)
        v_cmd = float(np.clip(cmd[0], -LIMO.max_linear, LIMO.max_linear))
        w_cmd = float(np.clip(cmd[1], -LIMO.max_angular, LIMO.max_angular))
        if accel_limits:
            v_act, w_act = _towards(v_act, v_cmd, LIMO.max_accel, dt), _towards(w_act, w_cmd, LIMO.max_yaw_accel, dt)
        else:
            v_act, w_act = v_cmd, w_cmd
        s = model.integrate(s, np.array([v_act, w_act]), dt)
        rxy, ryaw = s.position[:2].copy(), s.yaw

        def body_gap(c: np.ndarray, rxy: np.ndarray = rxy, ryaw: float = ryaw) -> float:
            return float(P.rectangle_gap(rxy[None], np.array([ryaw]), np.asarray(c)[None], PERSON)[0][0])

        for p in people:
            p.step(dt, body_gap, ep.statics, rxy)
        rec["t"].append(t + dt)
        rec["xy"].append(rxy)
        rec["yaw"].append(ryaw)
        rec["vel"].append(s.velocity[:2].copy())
        rec["om"].append(float(s.angular_velocity[2]))
        rec["vr"].append(float(u_ref[0]))
        rec["wr"].append(float(u_ref[1]))
        rec["u"].append(np.asarray(res.u, float)[:2].copy())
        rec["pp"].append(np.array([p.xy for p in people]).reshape(-1, 2))
        rec["y"].append(bool(res.yielding))
        rec["o"].append(int(res.object_rows))
        rec["sb"].append(floor is not None and floor.covers(_behind(rxy, ryaw)))
        rec["ev"].append(retreat is not None)
        if ep.goal_x is not None and goal_at is None and rxy[0] >= ep.goal_x:
            goal_at = t
        if goal_at is not None and t - goal_at >= 0.5:
            break
    n_p = len(people)
    return Trace(np.array(rec["t"]), np.array(rec["xy"]).reshape(-1, 2), np.array(rec["yaw"]),
                 np.array(rec["vel"]).reshape(-1, 2), np.array(rec["om"]), np.array(rec["vr"]), np.array(rec["wr"]),
                 np.array(rec["u"]).reshape(-1, 2), np.array(rec["pp"]).reshape(-1, n_p, 2),
                 np.array(rec["y"], bool), np.array(rec["o"], int), fallbacks, np.array(START[:2]), START[2],
                 time.perf_counter() - wall0, np.array(rec["sb"], bool), np.array(rec["ev"], bool))


# -- metrics -----------------------------------------------------------------------------------------

def episode_metrics(ep: Episode, tr: Trace) -> dict[str, Any]:
    """The metrics of one episode (module docstring) from its trace. Pure."""
    n = len(tr.t)
    dt = np.diff(np.concatenate([[0.0], tr.t]))
    prev_xy = np.vstack([tr.start_xy[None], tr.xy[:-1]])
    prev_yaw = np.concatenate([[tr.start_yaw], tr.yaw[:-1]])
    step = tr.xy - prev_xy
    dist = np.hypot(step[:, 0], step[:, 1])
    idle = (tr.v_ref == 0.0) & (tr.w_ref == 0.0)
    along = step[:, 0] * np.cos(prev_yaw) + step[:, 1] * np.sin(prev_yaw)
    unasked = tr.v_ref >= 0.0  # the operator did not ask for reverse
    # was the floor behind the body seen free before the step (the first step: as after it)
    seen_after = np.zeros(n, bool) if tr.seen_behind is None else tr.seen_behind
    prev_seen = np.concatenate([seen_after[:1], seen_after[:-1]]) if n else seen_after
    total = P.Contacts()
    min_sep = math.inf
    for i in range(tr.people.shape[1] if tr.people.ndim == 3 else 0):
        c = tr.people[:, i]
        gap, point = P.rectangle_gap(tr.xy, tr.yaw, c, PERSON)
        approach = P.approach_speed(tr.xy, tr.velocity, tr.omega, point, c)
        total = total + P.contacts(gap, approach)
        min_sep = min(min_sep, float(gap.min()) if n else math.inf)
    static_samples = static_episodes = 0
    min_static = math.inf
    for st in ep.statics:
        g = static_gap(tr.xy, tr.yaw, st) if n else np.zeros(0)
        static_samples += int((g < 0).sum())
        static_episodes += P.episodes(g < 0)
        if n:
            min_static = min(min_static, float(g.min()))
    speed = np.hypot(tr.velocity[:, 0], tr.velocity[:, 1]) if n else np.zeros(0)
    freeze = (tr.v_ref > 0) & (speed < FREEZE_SPEED)
    reached = time_to_goal = None
    if ep.goal_x is not None:
        hit = np.flatnonzero(tr.xy[:, 0] >= ep.goal_x)
        reached = bool(hit.size)
        time_to_goal = float(tr.t[hit[0]]) if hit.size else None
    return {"family": ep.family, "seed": ep.seed, "v_ref": ep.v_ref, "sigma": ep.sigma, "people": len(ep.walkers),
            "at_fault_contacts": total.at_fault_samples, "at_fault_episodes": total.at_fault_episodes,
            "max_at_fault_speed": total.max_at_fault_speed, "person_contacts": total.person_samples,
            "person_episodes": total.person_episodes, "static_contacts": static_samples,
            "static_episodes": static_episodes, "min_static_gap_m": min_static,
            "idle_displacement_m": float(dist[idle].sum()),
            "blind_reverse_m": float(np.maximum(-along[unasked & ~prev_seen], 0.0).sum()),
            "evading_steps": 0 if tr.evading is None else int(tr.evading.sum()),
            "min_separation_m": min_sep, "reachable": ep.goal_x is not None, "success": reached,
            "time_to_goal_s": time_to_goal, "nominal_time_s": None if ep.goal_x is None or ep.v_ref <= 0
            else (ep.goal_x - START[0]) / ep.v_ref, "time_stopped_s": float(dt[freeze].sum()),
            "yielding_steps": int(tr.yielding.sum()), "object_row_steps": int((tr.object_rows > 0).sum()),
            "fallbacks": dict(tr.fallbacks), "steps": n, "sim_s": float(tr.t[-1]) if n else 0.0,
            "wall_s": tr.wall_s, "params": ep.params}


def run_family(family: str, episodes: int, seed: int = 0, filt: SafetyFilter | None = None,
               progress: Any = None) -> tuple[list[dict[str, Any]], float]:
    """(rows, wall s) of ``episodes`` episodes of ``family``, seeds ``seed`` … ``seed + episodes - 1``."""
    filt = filt or SafetyFilter(FilterConfig())
    t0 = time.perf_counter()
    rows = []
    for k in range(episodes):
        ep = episode(family, seed + k)
        row = episode_metrics(ep, run_episode(ep, filt))
        rows.append(row)
        if progress is not None:
            progress(row)
    return rows, time.perf_counter() - t0


def _seeds(rows: list[dict[str, Any]], key: Any) -> list[int]:
    return [r["seed"] for r in rows if key(r)]


def summarise(rows: list[dict[str, Any]], wall_s: float) -> dict[str, Any]:
    """A family's totals, and the seeds of the episodes that miss a target."""
    reach = [r for r in rows if r["reachable"]]
    ok = [r for r in reach if r["success"]]
    ttg = [r["time_to_goal_s"] for r in ok]
    seeds = [r["seed"] for r in rows]
    return {
        "episodes": len(rows), "seeds": [min(seeds), max(seeds)] if seeds else [],
        "at_fault_contacts": sum(r["at_fault_contacts"] for r in rows),
        "at_fault_episodes": sum(r["at_fault_episodes"] > 0 for r in rows),
        "max_at_fault_speed": max((r["max_at_fault_speed"] for r in rows), default=0.0),
        "person_contacts": sum(r["person_contacts"] for r in rows),
        "person_episodes": sum(r["person_episodes"] > 0 for r in rows),
        "static_contacts": sum(r["static_contacts"] for r in rows),
        "static_episodes": sum(r["static_contacts"] > 0 for r in rows),
        "idle_displacement_max_m": max((r["idle_displacement_m"] for r in rows), default=0.0),
        "idle_displacement_total_m": float(sum(r["idle_displacement_m"] for r in rows)),
        "blind_reverse_max_m": max((r["blind_reverse_m"] for r in rows), default=0.0),
        "blind_reverse_total_m": float(sum(r["blind_reverse_m"] for r in rows)),
        "min_separation_m": min((r["min_separation_m"] for r in rows), default=math.inf),
        "min_static_gap_m": min((r["min_static_gap_m"] for r in rows), default=math.inf),
        "reachable": len(reach), "successes": len(ok), "success_rate": len(ok) / len(reach) if reach else None,
        "time_to_goal_median_s": float(np.median(ttg)) if ttg else None,
        "time_to_goal_max_s": max(ttg) if ttg else None,
        "time_stopped_mean_s": float(np.mean([r["time_stopped_s"] for r in rows])) if rows else 0.0,
        "time_stopped_max_s": max((r["time_stopped_s"] for r in rows), default=0.0),
        "fallback_steps": sum(sum(r["fallbacks"].values()) for r in rows),
        "evading_steps": sum(r.get("evading_steps", 0) for r in rows),
        "wall_s": wall_s, "sim_s": float(sum(r["sim_s"] for r in rows)),
        "missed": {"at_fault": _seeds(rows, lambda r: r["at_fault_contacts"] > 0),
                   "static": _seeds(rows, lambda r: r["static_contacts"] > 0),
                   "idle_displacement": _seeds(rows, lambda r: round(r["idle_displacement_m"], 2) > 0),
                   "blind_reverse": _seeds(rows, lambda r: round(r["blind_reverse_m"], 2) > 0),
                   "no_success": _seeds(reach, lambda r: not r["success"])},
    }


def _f(v: Any, digits: int = 2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v:.{digits}f}"


def table(summary: dict[str, Any]) -> str:
    """The families' markdown table (``tables.md`` and the RESULTS.md section)."""
    lines = ["| Family | Episodes (seeds) | At-fault contacts (samples / episodes) | Person's contacts (episodes) | "
             "Static contacts (episodes) | Idle displacement max (m) | Blind reverse max (m) | Min separation (m) | "
             "Success (reachable) | Time to goal p50 / max (s) | Time stopped mean / max (s) | Wall (s) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for fam, s in summary["families"].items():
        succ = ("–" if s["success_rate"] is None
                else f"{100 * s['success_rate']:.0f} % ({s['successes']}/{s['reachable']})")
        lines.append(f"| {fam} | {s['episodes']} ({s['seeds'][0]}–{s['seeds'][1]}) | {s['at_fault_contacts']} / "
                     f"{s['at_fault_episodes']} | {s['person_episodes']} | {s['static_episodes']} | "
                     f"{_f(s['idle_displacement_max_m'])} | {_f(s['blind_reverse_max_m'])} | "
                     f"{_f(s['min_separation_m'])} | {succ} | {_f(s['time_to_goal_median_s'], 1)} / "
                     f"{_f(s['time_to_goal_max_s'], 1)} | {_f(s['time_stopped_mean_s'], 1)} / "
                     f"{_f(s['time_stopped_max_s'], 1)} | {s['wall_s']:.0f} |")
    return "\n".join(lines)


def missed_lines(summary: dict[str, Any]) -> list[str]:
    out = []
    for fam, s in summary["families"].items():
        for what, seeds in s["missed"].items():
            if what == "no_success" and (s["success_rate"] is None or s["success_rate"] >= SUCCESS_TARGET):
                if not seeds:
                    continue
            if seeds:
                out.append(f"* {fam}, {what.replace('_', ' ')}: seeds {', '.join(map(str, seeds[:20]))}"
                           f"{' …' if len(seeds) > 20 else ''}")
    return out


def markdown(summary: dict[str, Any]) -> str:
    """``tables.md`` of a core run: the table, what it ran, the episodes that missed a target."""
    lines = [f"# riskfield bench crowd --mode core ({summary['episodes_per_family']} episodes per family)", "",
             *section_body(summary)]
    return "\n".join(lines) + "\n"


def section_body(summary: dict[str, Any]) -> list[str]:
    missed = missed_lines(summary)
    return [table(summary), "",
            f"`{summary['command']}`: {summary['wall_time_s']:.0f} s wall for {summary['sim_time_s']:.0f} s simulated; "
            f"the filter core (FilterConfig({'evade=True' if summary.get('evade') else ''})) in closed loop at "
            "50 Hz, ESDF (5 cm, planar) rebuilt at 10 Hz from the world "
            "0.1 s before, tracks 0.1 s old with N(0, σ) velocity noise (σ 0.15 m/s; `noise`: σ drawn in the "
            "range of the tracker's errors, `NOISE_SIGMA`), the LIMO's "
            "acceleration limits and a 0.04 s command delay (`riskfield/experiments/crowd_core.py` defines each "
            "family and metric; `emerging`'s 1–2 s lead counts from the camera's first sight of the person "
            "walking, not standing beside the path). Targets: 0 at-fault, 0 static contacts, "
            "idle displacement and blind reverse 0.00 m, "
            "success ≥ 95 % where the goal is reachable (idle families have none: –).", "",
            *(["Episodes that miss a target (family, target: seeds):", "", *missed] if missed
              else ["Every episode met every target."])]


def _markers(summary: dict[str, Any]) -> tuple[str, str]:
    """The run's section markers: the evading filter's table has its own section."""
    if not summary.get("evade"):
        return RESULTS_BEGIN, RESULTS_END
    tag = "crowd-core-evade"
    return RESULTS_BEGIN.replace("crowd-core", tag), RESULTS_END.replace("crowd-core", tag)


def results_section(summary: dict[str, Any]) -> str:
    """The RESULTS.md section between its markers (heading outside them stays)."""
    begin, end = _markers(summary)
    return "\n".join([begin, "", *section_body(summary), "", end])


def update_results(path: Path, summary: dict[str, Any]) -> None:
    """Rewrite the ``## Crowd families (core)`` section of ``path`` between its markers, or append it."""
    text = path.read_text() if path.is_file() else ""
    body = results_section(summary)
    begin, end = _markers(summary)
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.S)
    if pattern.search(text):
        text = pattern.sub(lambda _: body, text, count=1)
    else:
        heading = "with the opt-in evasion: `riskfield bench crowd --mode core --evade`" if summary.get("evade") \
            else "`riskfield bench crowd --mode core`"
        text = text.rstrip() + f"\n\n## Crowd families (core), {heading}\n\n" + body + "\n"
    path.write_text(text)
