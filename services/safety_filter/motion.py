"""Tracked objects (``map/objects``) → the moving-object table the barrier reads (``model``).

Pure: every time is an argument. :func:`object_table` turns the mapper's ``TrackedObjects`` into
rows [centre predicted to the instant the command takes effect, velocity, radius, risk group id,
speed uncertainty] (``model.OBJECT_COLUMNS``), keeping only what may move the barrier, bounded so
that a noisy estimate cannot brake for nothing:

* the speed passes a continuous deadband: 0 below ``object_speed_deadband``, ramping linearly
  to the full velocity at twice it (a standing person's estimate jitters around zero; a hard
  threshold would switch ∂h/∂t on and off from one map to the next and make the command jump);
* it counts only as far as the track's recent observations agree (``TrackEvidence``): the speed
  along the newest velocity's direction that each of the last ``object_evidence`` observations
  shows. A walker's velocity persists from one map to the next; a standing person's noise points
  anywhere, so its estimate rarely survives: for a standing person at σ = 0.29 m/s per axis,
  3 observations leave a speed above the deadband in 4.6 % of maps instead of 78.5 % (0.4 % instead
  of 40.8 % at 0.15 m/s; ``tests/safety_filter/test_motion.py``, ``counted``, 5000 maps);
* it is capped at ``object_speed_cap``;
* a young track counts with the fraction ``tracked_ms / object_young_ms`` of its velocity, and
  an object not observed for ``object_stale_ms`` counts not at all;
* the centre is predicted from the object's own observation (the message's stamp less its
  ``age_ms``) to the instant the command takes effect (now + ``command_delay_s``).

Objects that end up with zero velocity are left out: a static object is in the ESDF already.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from riskfield.protocol import TrackedObject

from .config import MotionParams
from .model import OBJ_GROUP, OBJ_RADIUS, OBJ_SIGMA, OBJ_VX, OBJ_X, OBJECT_COLUMNS


class TrackEvidence:
    """Per track, the velocities of its last ``observations`` observations, each counted once
    (by its own time, the message's stamp less its ``age_ms``: a map that repeats an old
    observation adds nothing). Pure: the caller hands it every ``TrackedObjects`` it takes."""

    def __init__(self, observations: int):
        if observations < 1:
            raise ValueError("observations must be at least 1")
        self.observations = observations
        self._seen: dict[int, list[tuple[int, np.ndarray]]] = {}

    def observe(self, objects: Sequence[TrackedObject], stamp_ns: int) -> None:
        """Takes one message's objects; a track absent from it is forgotten (ids are never reused)."""
        seen: dict[int, list[tuple[int, np.ndarray]]] = {}
        for obj in objects:
            at = stamp_ns - round(obj.age_ms * 1e6)
            past = self._seen.get(obj.id, [])
            if past and past[-1][0] >= at:
                seen[obj.id] = past
                continue
            seen[obj.id] = [*past, (at, np.asarray(obj.velocity, np.float64))][-self.observations:]
        self._seen = seen

    def supported_speed(self, obj: TrackedObject) -> float:
        """The speed along ``obj``'s velocity that each remembered observation of its track shows
        (its own speed when there is none: a young track is weighted by ``object_young_ms``)."""
        v = np.asarray(obj.velocity, np.float64)
        speed = float(np.linalg.norm(v))
        if not speed > 0.0:
            return 0.0
        along = [float(u @ v) / speed for _, u in self._seen.get(obj.id, ())]
        return max(min([speed, *along]), 0.0)


def effective_velocity(obj: TrackedObject, p: MotionParams, evidence: TrackEvidence | None = None) -> np.ndarray:
    """The velocity (m/s) an object adds to the barrier: evidence, deadband, cap and track-age
    weights applied."""
    v = np.asarray(obj.velocity, np.float64)
    speed = float(np.linalg.norm(v))
    if not math.isfinite(speed) or speed == 0.0:
        return np.zeros(3)
    if evidence is not None:
        v = v * (evidence.supported_speed(obj) / speed)
        speed = float(np.linalg.norm(v))
        if speed == 0.0:
            return np.zeros(3)
    db = p.object_speed_deadband
    ramp = 1.0 if db == 0.0 else min(max((speed - db) / db, 0.0), 1.0)
    young = 1.0 if p.object_young_ms == 0.0 else min(obj.tracked_ms / p.object_young_ms, 1.0)
    fresh = obj.age_ms <= p.object_stale_ms
    scale = ramp * young * fresh * min(1.0, p.object_speed_cap / speed)
    return v * scale


def object_table(objects: Sequence[TrackedObject], p: MotionParams, now_ns: int, objects_stamp_ns: int,
                 near: np.ndarray | None = None, max_objects: int = 16,
                 evidence: TrackEvidence | None = None) -> np.ndarray:
    """(k, ``OBJECT_COLUMNS``) rows of the objects that move, predicted to ``now_ns`` (the step's
    wall clock) + ``command_delay_s``, the ``max_objects`` nearest ``near`` (the robot's position)
    first; ``evidence`` (which has taken this message) bounds each speed by its track's history."""
    since = (now_ns - objects_stamp_ns) * 1e-9 + p.command_delay_s
    rows = []
    for obj in objects:
        v = effective_velocity(obj, p, evidence)
        if not v.any() or obj.risk_group == 0:
            continue
        row = np.zeros(OBJECT_COLUMNS)
        ahead = max(since + obj.age_ms * 1e-3, 0.0)
        row[OBJ_X:OBJ_X + 3] = np.asarray(obj.position, np.float64) + v * ahead
        row[OBJ_VX:OBJ_VX + 3] = v
        row[OBJ_RADIUS], row[OBJ_GROUP], row[OBJ_SIGMA] = obj.radius, obj.risk_group, p.object_speed_sigma
        rows.append(row)
    if not rows:
        return np.zeros((0, OBJECT_COLUMNS))
    table = np.array(rows)
    if near is not None and len(table) > max_objects:
        d = np.linalg.norm(table[:, OBJ_X:OBJ_X + 2] - np.asarray(near, np.float64)[:2], axis=1)
        table = table[np.argsort(d, kind="stable")]
    return np.ascontiguousarray(table[:max_objects])
