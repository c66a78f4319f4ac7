"""Metrics of a robot among moving people, from ground truth: ``riskfield bench crowd`` and the demo's
walker. Pure functions of time series (no I/O), so each is unit-tested on its own.

* **gap** — the planar distance between the robot's body (the LIMO rectangle, ``length × width``
  centred on the base, x forward: ``safety_filter.config``) and a person's upright cylinder;
  < 0 is a contact (the overlap depth).
* **at-fault contact** — a contact while the robot's body point nearest the person moves towards
  them faster than ``AT_FAULT_SPEED`` (rigid-body velocity of that point, v + ω × r, projected on
  the direction to the person's centre). A contact with the robot stopped or moving away is counted
  separately, as the person's: a robot cannot avoid being walked into.
* **ghost time** — after people leave the robot's way (``relevant`` turns false), how long the
  safety filter keeps the command below ``GHOST_FRACTION`` of the reference: the time from the
  departure to the first filtered command at ≥ 80 % of a non-zero reference (to the end of the
  record if it never recovers; time under a fail-safe brake not counted). A person is *relevant*
  (slowing for them is the filter's job) while not behind the robot and within ``RELEVANT_GAP`` of
  its body: the high-risk group's CBF (α = 0.6, margin 0.15 m, look-ahead 0.25 m) holds a 0.5 m/s
  robot below 80 % only within about 0.67 m of the inflated person ahead of the look-ahead point,
  so 1.1 m of body gap covers it.
* **tracker accuracy** — each tracked person of ``map/objects`` against the true person nearest
  it (within ``TRACK_MATCH``) at the instant it was observed (the message stamp minus ``age_ms``):
  the velocity error per axis (its RMS, and the σ of its median magnitude, robust to the tail the
  tracker's lag at a walker's stops and turns makes: what the filter's ``object_speed_sigma`` and
  the core bench's noise family stand for) and the position error, over the tracks old enough for
  the filter to count their whole velocity (``object_young_ms``) and over all.
* **map lag** — for a map received at r (built from a frame stamped s), the map shows the
  person where they truly were at r − lag: lag = (r − s) + τ, τ the time shift that best fits the
  centroid of the map's high-risk cells near the person to the person's true track. Only while the
  person walks (a standing one fits every shift). The map sees the person's near side, so the
  centroid sits up to a radius towards the camera: a head-on walker reads slightly early.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from riskfield.protocol.platforms import LIMO
from riskfield.services.safety_filter.config import LIMO_LENGTH, LIMO_WIDTH

#: m/s: the nearest body point must move towards the person faster than this for an at-fault contact
AT_FAULT_SPEED = 0.05
#: the filtered command below this fraction of the reference is "held back"
GHOST_FRACTION = 0.8
#: m: a person nearer than this to the robot's body (and not behind it) may rightly slow it
RELEVANT_GAP = 1.1
#: m/s: a reference below this is a stop, not a speed to keep
MIN_REFERENCE = 0.05
#: m: a track farther than this from every true person is a false track, not an error
TRACK_MATCH = 0.6


def body_frame(robot_xy: np.ndarray, yaw: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Planar ``points`` (N, 2) in the robot's body frame (x forward), one robot pose per row."""
    d = np.asarray(points, float) - np.asarray(robot_xy, float)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def rectangle_gap(robot_xy: np.ndarray, yaw: np.ndarray, centre: np.ndarray, radius: float | np.ndarray,
                  length: float = LIMO_LENGTH, width: float = LIMO_WIDTH) -> tuple[np.ndarray, np.ndarray]:
    """(gap, nearest body point) per row: the signed planar distance from the robot's rectangle to a
    circle of ``radius`` about ``centre`` (< 0: overlap), and the world point of the rectangle
    nearest the circle's centre (the centre itself when it lies inside the rectangle)."""
    robot_xy, yaw = np.atleast_2d(np.asarray(robot_xy, float)), np.atleast_1d(np.asarray(yaw, float))
    q = body_frame(robot_xy, yaw, np.atleast_2d(centre))
    hx, hy = length / 2, width / 2
    near = np.column_stack([np.clip(q[:, 0], -hx, hx), np.clip(q[:, 1], -hy, hy)])
    outside = np.hypot(q[:, 0] - near[:, 0], q[:, 1] - near[:, 1])
    inside = np.minimum(hx - np.abs(q[:, 0]), hy - np.abs(q[:, 1]))  # depth when the centre is inside
    dist = np.where(outside > 0, outside, -np.maximum(inside, 0.0))
    c, s = np.cos(yaw), np.sin(yaw)
    world = robot_xy + np.column_stack([c * near[:, 0] - s * near[:, 1], s * near[:, 0] + c * near[:, 1]])
    return dist - np.asarray(radius, float), world


def approach_speed(robot_xy: np.ndarray, velocity: np.ndarray, omega: np.ndarray, point: np.ndarray,
                   centre: np.ndarray) -> np.ndarray:
    """Speed (m/s, > 0 towards) at which the body ``point`` moves towards the person's ``centre``: the
    rigid-body velocity v + ω × (point − robot) projected on the unit vector from the point to the
    centre (from the robot's centre when the point is the centre, i.e. the centre is inside)."""
    r = np.asarray(point, float) - np.asarray(robot_xy, float)
    omega = np.asarray(omega, float)
    v = np.asarray(velocity, float) + np.column_stack([-omega * r[:, 1], omega * r[:, 0]])
    d = np.asarray(centre, float) - np.asarray(point, float)
    n = np.hypot(d[:, 0], d[:, 1])
    fallback = np.asarray(centre, float) - np.asarray(robot_xy, float)
    d = np.where((n > 1e-9)[:, None], d, fallback)
    n = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    return (v * d).sum(axis=1) / n


def episodes(mask: np.ndarray) -> int:
    """Number of separate runs of True."""
    m = np.asarray(mask, dtype=bool)
    return int(np.count_nonzero(m[1:] & ~m[:-1]) + (1 if m.size and m[0] else 0))


@dataclass
class Contacts:
    """Contacts with one person along a trajectory: samples and episodes (runs of samples), at fault
    (the robot moving towards them) or the person's; the fastest at-fault approach (m/s)."""

    at_fault_samples: int = 0
    at_fault_episodes: int = 0
    person_samples: int = 0
    person_episodes: int = 0
    max_at_fault_speed: float = 0.0

    def __add__(self, other: Contacts) -> Contacts:
        return Contacts(self.at_fault_samples + other.at_fault_samples,
                        self.at_fault_episodes + other.at_fault_episodes,
                        self.person_samples + other.person_samples, self.person_episodes + other.person_episodes,
                        max(self.max_at_fault_speed, other.max_at_fault_speed))


def contacts(gap: np.ndarray, approach: np.ndarray, threshold: float = AT_FAULT_SPEED) -> Contacts:
    """Classify the contact samples (gap < 0) by the approach speed of the nearest body point."""
    touching = np.asarray(gap) < 0
    fault = touching & (np.asarray(approach) > threshold)
    person = touching & ~fault
    return Contacts(int(fault.sum()), episodes(fault), int(person.sum()), episodes(person),
                    float(np.max(np.asarray(approach)[fault])) if fault.any() else 0.0)


def relevant(robot_xy: np.ndarray, yaw: np.ndarray, centres: Sequence[np.ndarray], gaps: Sequence[np.ndarray],
             max_gap: float = RELEVANT_GAP, length: float = LIMO_LENGTH) -> np.ndarray:
    """Per sample: some person is within ``max_gap`` of the body and not behind it (their centre's
    body-frame x ≥ −length/2), so slowing down for them is right."""
    out = np.zeros(len(robot_xy), bool)
    for c, g in zip(centres, gaps, strict=True):
        ahead = body_frame(robot_xy, yaw, c)[:, 0] >= -length / 2
        out |= ahead & (np.asarray(g) <= max_gap)
    return out


def command_ratio(t: np.ndarray, t_ref: np.ndarray, v_ref: np.ndarray, t_safe: np.ndarray,
                  v_safe: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(filtered / reference forward speed, reference valid) at times ``t``: the latest command of
    each stream at or before each time (nan before the first)."""
    def latest(ts: np.ndarray, vs: np.ndarray) -> np.ndarray:
        i = np.searchsorted(np.asarray(ts), t, side="right") - 1
        return np.where(i >= 0, np.asarray(vs, float)[np.clip(i, 0, None)] if len(vs) else np.nan, np.nan)

    ref, safe = latest(t_ref, v_ref), latest(t_safe, v_safe)
    valid = np.isfinite(ref) & np.isfinite(safe) & (ref > MIN_REFERENCE)
    return np.where(valid, safe / np.where(valid, ref, 1.0), np.nan), valid


@dataclass
class Ghost:
    """The longest hold after a departure (s), whether it lasted to the end of the record, and every
    departure's hold."""

    time_s: float = 0.0
    censored: bool = False
    holds: list[float] = field(default_factory=list)


def ghost_time(t: np.ndarray, ratio: np.ndarray, valid: np.ndarray, relevant_mask: np.ndarray,
               excluded: np.ndarray | None = None, fraction: float = GHOST_FRACTION) -> Ghost:
    """For each departure (``relevant_mask`` True → False), the time until the filtered command is
    back at ≥ ``fraction`` of the reference (samples with a valid reference only), or until a person
    is relevant again (the hold is theirs from then on), or to the end of the record (censored);
    the longest. Time in ``excluded`` samples (the filter's fail-safe brakes: a stale or missing
    map holds the robot whatever the map shows) is not counted, though the hold goes on through it."""
    t = np.asarray(t, float)
    rel = np.asarray(relevant_mask, bool)
    ok = np.asarray(valid, bool) & (np.nan_to_num(np.asarray(ratio, float), nan=0.0) >= fraction)
    skip = np.zeros(len(t), bool) if excluded is None else np.asarray(excluded, bool)
    dt = np.diff(t, append=t[-1]) if len(t) else t
    out = Ghost()
    for i in np.flatnonzero(rel[:-1] & ~rel[1:]) + 1:
        j = i
        while j < len(t) and not ok[j] and not rel[j]:
            j += 1
        hold = float(dt[i:j][~skip[i:j]].sum())
        censored = bool(j == len(t))
        out.holds.append(hold)
        if hold > out.time_s or (hold == out.time_s and censored):
            out.time_s, out.censored = hold, censored
    return out


def in_view(robot_xy: np.ndarray, yaw: np.ndarray, centres: np.ndarray, radius: float = 0.0,
            hfov_deg: float = 90.0, camera_x: float = LIMO.camera.position[0], max_range: float = 8.0) -> np.ndarray:
    """Per sample: the person's centre is inside the camera's horizontal field of view (shrunk by
    the angle the person's ``radius`` subtends, so the whole width is seen) and within range."""
    q = body_frame(robot_xy, yaw, centres) - (camera_x, 0.0)
    r = np.hypot(q[:, 0], q[:, 1])
    bearing = np.abs(np.arctan2(q[:, 1], q[:, 0]))
    half = math.radians(hfov_deg) / 2 - np.arcsin(np.clip(radius / np.maximum(r, 1e-9), 0, 1))
    return (q[:, 0] > 0) & (bearing <= half) & (r <= max_range)


def seen_before(t: np.ndarray, view: np.ndarray, t_conflict: float, window: float = 3.0) -> float:
    """How long (s) the person was in view during the ``window`` seconds before ``t_conflict`` (at the
    contact itself the person is too close and too wide for the camera: what counts is having been
    seen on the way)."""
    t, view = np.asarray(t, float), np.asarray(view, bool)
    if len(t) < 2:
        return 0.0
    dt = np.diff(t, append=t[-1])
    sel = view & (t >= t_conflict - window) & (t < t_conflict)
    return float(dt[sel].sum())


class Track:
    """A person's true floor position over time, linearly interpolated (the simulator's actors are
    piecewise linear in time, so this is exact between corners)."""

    def __init__(self, t: np.ndarray, xy: np.ndarray, velocity: np.ndarray | None = None, radius: float = 0.22):
        order = np.argsort(t)
        self.t = np.asarray(t, float)[order]
        self.xy = np.asarray(xy, float).reshape(-1, 2)[order]
        self.v = (np.zeros_like(self.xy) if velocity is None else np.asarray(velocity, float).reshape(-1, 2)[order])
        self.radius = float(radius)

    def at(self, t: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        return np.column_stack([np.interp(t, self.t, self.xy[:, 0]), np.interp(t, self.t, self.xy[:, 1])])

    def speed_at(self, t: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        i = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1)
        return np.hypot(self.v[i, 0], self.v[i, 1])

    def velocity_at(self, t: np.ndarray) -> np.ndarray:
        """The velocity of the segment each time falls in (piecewise constant, as the actors' plans)."""
        t = np.atleast_1d(np.asarray(t, float))
        i = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1)
        return self.v[i]

    def present(self, t: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        return (t >= self.t[0]) & (t <= self.t[-1] + 0.5)


def map_centroid(cells_xy: np.ndarray, near: np.ndarray, within: float = 1.0) -> np.ndarray | None:
    """Centroid of the map's person cells (N, 2) within ``within`` of ``near``; None if none."""
    if not len(cells_xy):
        return None
    sel = np.hypot(*(np.asarray(cells_xy) - near).T) <= within
    return np.asarray(cells_xy)[sel].mean(axis=0) if sel.any() else None


def best_shift(track: Track, stamp: float, centroid: np.ndarray, max_shift: float = 2.0, step: float = 0.01
               ) -> tuple[float, float]:
    """(τ, residual m): the shift τ ∈ [−0.5, max_shift] s for which the person's true position at
    ``stamp − τ`` is nearest ``centroid``."""
    taus = np.arange(-0.5, max_shift + step / 2, step)
    d = np.hypot(*(track.at(stamp - taus) - centroid).T)
    k = int(np.argmin(d))
    return float(taus[k]), float(d[k])


def percentile(values: Sequence[float], q: float) -> float | None:
    vals = [float(v) for v in values if v is not None and math.isfinite(v)]
    return float(np.percentile(vals, q)) if vals else None


@dataclass
class TrackerErrors:
    """Raw tracker errors (``tracker_errors``), pooled over cases by ``+``."""

    velocity: list[list[float]] = field(default_factory=list)  # (dvx, dvy) per matched track
    settled: list[bool] = field(default_factory=list)
    position: list[float] = field(default_factory=list)
    false_tracks: int = 0

    def __add__(self, other: TrackerErrors) -> TrackerErrors:
        return TrackerErrors(self.velocity + other.velocity, self.settled + other.settled,
                             self.position + other.position, self.false_tracks + other.false_tracks)

    def summary(self) -> dict[str, float | int | None]:
        dv = np.asarray(self.velocity, float).reshape(-1, 2)
        settled = dv[np.asarray(self.settled, bool)] if len(dv) else dv

        def axis_rms(d: np.ndarray) -> float | None:
            return float(np.sqrt(np.mean(np.square(d)))) if len(d) else None

        speed_err = np.hypot(settled[:, 0], settled[:, 1]).tolist()
        return {"matched": len(dv), "settled": len(settled), "false_tracks": self.false_tracks,
                "velocity_sigma_settled_m_s": axis_rms(settled), "velocity_sigma_all_m_s": axis_rms(dv),
                # σ of a 2-D normal error from its median magnitude (Rayleigh: median = σ √(2 ln 2)),
                # which the tracker's lag at a walker's stops and turns (the RMS's tail) leaves alone
                "velocity_sigma_robust_m_s": None if not speed_err else
                float(np.median(speed_err)) / math.sqrt(2 * math.log(2)),
                "velocity_error_p50_m_s": percentile(speed_err, 50),
                "velocity_error_p95_m_s": percentile(speed_err, 95),
                "position_error_p50_m": percentile(self.position, 50),
                "position_error_p95_m": percentile(self.position, 95)}


def tracker_errors(observations: Sequence[tuple[float, float, np.ndarray, np.ndarray]], tracks: Sequence[Track],
                   settled_ms: float) -> TrackerErrors:
    """The tracker's errors against the truth (module doc). ``observations``: per tracked person,
    (observation time s, tracked_ms, position xy, velocity xy); ``settled_ms``: the age from which
    a track's velocity counts whole."""
    out = TrackerErrors()
    for t, tracked_ms, xy, v in observations:
        here = [(float(np.hypot(*(tr.at(t)[0] - xy))), tr) for tr in tracks if tr.present(np.array([t]))[0]]
        gap, tr = min(here, key=lambda g: g[0], default=(math.inf, None))
        if tr is None or gap > TRACK_MATCH:
            out.false_tracks += 1
            continue
        dv = np.asarray(v, float)[:2] - tr.velocity_at(t)[0]
        out.velocity.append([round(float(dv[0]), 4), round(float(dv[1]), 4)])
        out.settled.append(bool(tracked_ms >= settled_ms))
        out.position.append(round(gap, 4))
    return out
