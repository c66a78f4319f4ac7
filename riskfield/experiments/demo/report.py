"""The demo's report: what happened, measured against ground truth, from the MCAP recording.

Everything here is computed after the run from the recording (what was on the wire, with
receive times) and the scenario (ground-truth geometry), so a report can be made again from a
saved run: ``riskfield demo --report-only --out DIR``.

- clearance to an object = ground-truth signed distance from the robot's centre to the object's
  surface (open3d, at the body's heights) minus the robot radius; < 0 is a collision;
- first intervention distance = that clearance when the safety filter first modifies the
  operator's command while the robot is heading at the object;
- command latency = time from a ``cmd/ref`` sample to the next ``cmd/safe`` sample (both as
  received by the recorder, so both Zenoh hops are included).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from riskfield.protocol import DecodeError, NodeStatus, RobotState, SafetyStatus, VelocityCommand, decode
from riskfield.services.recorder.mcap_io import read_records

BODY_HEIGHTS = (0.08, 0.2)


@dataclass
class Streams:
    """Decoded time series (seconds since the first record)."""

    t0_ns: int = 0
    state_t: list[float] = field(default_factory=list)
    xy: list[tuple[float, float]] = field(default_factory=list)
    yaw: list[float] = field(default_factory=list)
    status_t: list[float] = field(default_factory=list)
    status: list[SafetyStatus] = field(default_factory=list)
    ref_t: list[float] = field(default_factory=list)
    ref: list[VelocityCommand] = field(default_factory=list)
    safe_t: list[float] = field(default_factory=list)
    safe: list[VelocityCommand] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    node_status: dict[str, NodeStatus] = field(default_factory=dict)
    duration_s: float = 0.0


def load_streams(mcap_path: str | Path, root: str) -> Streams:
    s = Streams()
    first = None
    last = 0
    for rec in read_records(mcap_path):
        if first is None:
            first = rec.log_time_ns
            s.t0_ns = first
        t = (rec.log_time_ns - first) / 1e9
        last = rec.log_time_ns
        rel = rec.key[len(root) + 1:] if rec.key.startswith(root + "/") else rec.key
        s.counts[rel] += 1
        try:
            if rel == "state":
                m = decode(rec.payload, RobotState)
                s.state_t.append(t)
                s.xy.append((m.position[0], m.position[1]))
                s.yaw.append(m.yaw)
            elif rel == "safety/status":
                s.status_t.append(t)
                s.status.append(decode(rec.payload, SafetyStatus))
            elif rel == "cmd/ref":
                s.ref_t.append(t)
                s.ref.append(decode(rec.payload, VelocityCommand))
            elif rel == "cmd/safe":
                s.safe_t.append(t)
                s.safe.append(decode(rec.payload, VelocityCommand))
            elif rel.startswith("status/"):
                s.node_status[rel.split("/", 1)[1]] = decode(rec.payload, NodeStatus)
        except DecodeError:
            s.counts["invalid:" + rel] += 1
    s.duration_s = (last - (first or last)) / 1e9
    return s


def _stats(x: list[float] | np.ndarray) -> dict[str, float] | None:
    a = np.asarray(x, dtype=float)
    if a.size == 0:
        return None
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "p99": float(np.percentile(a, 99)),
            "max": float(a.max()), "n": int(a.size)}


def command_latency_ms(ref_t: list[float], safe_t: list[float]) -> list[float]:
    """For each reference, the delay to the next filtered command (ms)."""
    safe = np.asarray(safe_t)
    out = []
    for t in ref_t:
        i = int(np.searchsorted(safe, t, side="left"))
        if i < len(safe):
            out.append((safe[i] - t) * 1e3)
    return out


def episodes(mask: np.ndarray) -> int:
    """Number of separate runs of True in a boolean series."""
    m = np.asarray(mask, dtype=bool)
    return int(np.count_nonzero(m[1:] & ~m[:-1]) + (1 if m.size and m[0] else 0))


def first_intervention(status_t: np.ndarray, intervening: np.ndarray, window: tuple[float, float]
                       ) -> float | None:
    sel = (status_t >= window[0]) & (status_t <= window[1]) & intervening
    idx = np.flatnonzero(sel)
    return float(status_t[idx[0]]) if idx.size else None


def interp(t: float, ts: np.ndarray, v: np.ndarray) -> float:
    return float(np.interp(t, ts, v))


def clearance_series(scene_for, names: list[str], t: np.ndarray, xy: np.ndarray, radius: float,
                     t_sim0: float = 0.0) -> dict[str, np.ndarray]:
    """Clearance to each named object (and ``"all"``) along the trajectory.

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


def fmt(v: Any, unit: str = "", digits: int = 2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v:.{digits}f}{unit}"
