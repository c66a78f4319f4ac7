"""The paper's teleoperation experiment (Fig. 5), as ``riskfield demo`` and ``riskfield bench
teleop`` run it: the scripted operator service drives the robot at a target, the safety filter
decides how close it gets.

Metrics of one approach, from ground-truth distances along the driven trajectory:

* an **intervention** is a filter step that changed the command to stay safe (``SafetyStatus``
  with ``intervening`` and no ``fallback``: a fail-safe brake is not a CBF intervention);
* the **first-intervention distance** is the distance to the obstacle at the time of the first
  intervention, linearly interpolated between the robot states around it;
* the **minimum clearance** is the smallest distance over the approach.

The demo measures from the robot's centre minus its radius (``scenarios.clearance_series``);
the bench from the look-ahead point the filter constrains (the paper's plotted ``d(p_L)``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from riskfield.protocol import Keys, NodeStatus, SafetyStatus, decode
from riskfield.services.runtime.processes import wait_until

#: the paper's hardware numbers (m), per obstacle class
PAPER = {"ball": {"first_intervention_m": 0.36, "min_clearance_m": 0.14},
         "dog": {"first_intervention_m": 0.56, "min_clearance_m": 0.41}}
#: the look-ahead distance (m) of the LIMO's filter
LOOKAHEAD = 0.25


def operator_args(targets: Sequence[tuple[str, float, float]], seed: int, push_s: float) -> list[str]:
    """The operator service's settings for visiting ``targets`` ((name, x, y), in order)."""
    return ["--set", f"targets={json.dumps([list(t) for t in targets])}", "--set", f"seed={seed}",
            "--set", f"push_s={push_s}"]


def wait_operator_done(session: Any, keys: Keys, n_targets: int, timeout_s: float) -> bool:
    """Wait until the operator has visited its ``n_targets`` targets (its ``NodeStatus`` counter
    ``target_index``); False after ``timeout_s``."""
    latest: list[NodeStatus] = []
    sub = session.declare_subscriber(keys.status("operator"),
                                     lambda smp: latest.append(decode(smp.payload.to_bytes(), NodeStatus)))
    try:
        return wait_until(lambda: bool(latest) and int(latest[-1].extra.get("target_index", 0)) >= n_targets,
                          timeout_s, period_s=0.1)
    finally:
        sub.undeclare()


def is_intervention(status: SafetyStatus) -> bool:
    """The filter changed the command to stay safe (not a fail-safe brake)."""
    return bool(status.intervening and status.fallback is None)


def first_intervention(status_t: np.ndarray, intervening: np.ndarray,
                       window: tuple[float, float] = (-math.inf, math.inf)) -> float | None:
    """Time of the first intervention within ``window``; None if there was none."""
    status_t = np.asarray(status_t, dtype=float)
    sel = (status_t >= window[0]) & (status_t <= window[1]) & np.asarray(intervening, dtype=bool)
    idx = np.flatnonzero(sel)
    return float(status_t[idx[0]]) if idx.size else None


def distance_at(t_query: float, t: np.ndarray, distance: np.ndarray) -> float:
    """The distance at ``t_query``, linearly interpolated between the states around it."""
    return float(np.interp(t_query, t, distance))


def approach(t: np.ndarray, distance: np.ndarray, t_intervention: float | None) -> tuple[float | None, float]:
    """(first-intervention distance or None, minimum clearance) of one approach."""
    first = None if t_intervention is None or not len(t) else distance_at(t_intervention, t, distance)
    return first, float(np.min(distance))


@dataclass
class Trace:
    """One bench run's time series (seconds from the operator's start) and its metrics."""

    t: np.ndarray
    centre_distance: np.ndarray
    lookahead_distance: np.ndarray
    t_cmd: np.ndarray
    v_ref: np.ndarray
    w_ref: np.ndarray
    t_safe: np.ndarray
    v_safe: np.ndarray
    w_safe: np.ndarray
    t_intervention: float | None

    def metrics(self) -> dict[str, float | None]:
        first, least = approach(self.t, self.lookahead_distance, self.t_intervention)
        first_c, least_c = approach(self.t, self.centre_distance, self.t_intervention)
        return dict(first_intervention_m=first, min_clearance_m=least,
                    first_intervention_centre_m=first_c, min_clearance_centre_m=least_c)


def trace_of(rec: Any, distance: Any, t0: float) -> Trace:
    """A ``Trace`` from a ``stack.Recorder`` of ``state``, ``ref``, ``safe`` and ``status``."""
    states = rec.snapshot("state")
    refs = rec.snapshot("ref")
    safes = rec.snapshot("safe")
    status = rec.snapshot("status")
    t = np.array([a for a, _ in states]) - t0
    xy = np.array([m.position[:2] for _, m in states]).reshape(-1, 2)
    yaw = np.array([m.yaw for _, m in states])
    la = xy + LOOKAHEAD * np.column_stack([np.cos(yaw), np.sin(yaw)]) if len(xy) else xy
    cd = distance(xy) if len(xy) else np.zeros(0)
    ld = distance(la) if len(xy) else np.zeros(0)
    st = np.array([a for a, _ in status]) - t0 if status else np.zeros(0)
    first = first_intervention(st, np.array([is_intervention(s) for _, s in status], dtype=bool))

    def series(items):
        if not items:
            return np.zeros(0), np.zeros(0), np.zeros(0)
        return (np.array([a for a, _ in items]) - t0, np.array([m.linear[0] for _, m in items]),
                np.array([m.angular[2] for _, m in items]))

    tr, vr, wr = series(refs)
    ts, vs, ws = series(safes)
    return Trace(t, cd, ld, tr, vr, wr, ts, vs, ws, first)
