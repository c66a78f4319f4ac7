"""The demo's report: what happened, measured against ground truth, from the MCAP recording.

Everything here is computed after the run from the recording (what was on the wire, with
receive times) and the scenario (ground-truth geometry), so a report can be made again from a
saved run: ``riskfield demo --report-only --out DIR``. The metrics are the experiments' own
(``riskfield.experiments.teleop``, ``.navigation``, ``.scenarios``), shared with the benches:

- clearance to an object = ground-truth signed distance from the robot's centre to the object's
  surface (open3d, at the body's heights) minus the robot radius; < 0 is a collision;
- first intervention distance = that clearance when the safety filter first modifies the
  operator's command while the robot is heading at the object;
- command latency, camera → ``cmd/safe`` latency, ESDF content and arrival age, and the time per
  stage (``pipeline_stages``): as defined in ``riskfield/experiments/latency.py``, where they are
  computed; the nodes' own timings (render, perception, integration, ESDF) come from their
  ``status/*`` snapshots;
- people (``people_summary``): the simulator's ground truth of the walking people (``sim/actors``)
  against the robot's body, as ``riskfield bench crowd`` measures it (``riskfield.experiments.people``):
  the smallest clearance between the LIMO rectangle and a person's cylinder, contacts at fault (the
  robot moving towards the person) or the person's, and the ghost time after the crossing walker
  left the robot's way (fail-safe brakes not counted).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rich.console import Console
from rich.table import Table

from riskfield.protocol import (
    DecodeError,
    EsdfGrid,
    NodeStatus,
    RobotState,
    SafetyStatus,
    SimActors,
    VelocityCommand,
    decode,
)
from riskfield.protocol.keys import base_of
from riskfield.services.recorder.mcap_io import iter_mcap, latest_recording, raw_key, read_records
from riskfield.services.simulator.scene import Scene

from .. import people as P
from ..latency import STAGES, command_latency_ms, latency_summary, latency_table
from ..navigation import polyline_distance
from ..scenarios import LOOP, TELEOP_TARGETS, TRACKED, UNSEEN, clearance_series, collisions, scenario, scene_objects
from ..teleop import distance_at, first_intervention, is_intervention
from ..timing import timing_stats

if TYPE_CHECKING:
    from .config import DemoConfig

@dataclass
class Streams:
    """Decoded time series (seconds since the first record)."""

    t0_ns: int = 0
    state_t: list[float] = field(default_factory=list)
    xy: list[tuple[float, float]] = field(default_factory=list)
    yaw: list[float] = field(default_factory=list)
    velocity: list[tuple[float, float]] = field(default_factory=list)  # world frame
    omega: list[float] = field(default_factory=list)
    actors_t: list[float] = field(default_factory=list)
    actors: list[SimActors] = field(default_factory=list)
    status_t: list[float] = field(default_factory=list)
    status: list[SafetyStatus] = field(default_factory=list)
    ref_t: list[float] = field(default_factory=list)
    ref: list[VelocityCommand] = field(default_factory=list)
    safe_t: list[float] = field(default_factory=list)
    safe: list[VelocityCommand] = field(default_factory=list)
    esdf_t: list[float] = field(default_factory=list)
    esdf_stamp: list[float] = field(default_factory=list)  # header stamps, same time base as the ``_t``
    counts: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    node_status: dict[str, NodeStatus] = field(default_factory=dict)
    # every status snapshot's extra numbers: service → name → values over the run
    node_extra: dict[str, dict[str, list[float]]] = field(
        default_factory=lambda: defaultdict(lambda: defaultdict(list)))
    # (receive time, header stamp) of the stamped stages (``STAGES``), same time base as the ``_t``
    stamped: dict[str, list[tuple[float, float]]] = field(default_factory=lambda: defaultdict(list))
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
        rel = base_of(rec.key[len(root) + 1:]) if rec.key.startswith(root + "/") else rec.key
        s.counts[rel] += 1
        try:
            if rel == "state":
                m = decode(rec.payload, RobotState)
                s.state_t.append(t)
                s.xy.append((m.position[0], m.position[1]))
                s.yaw.append(m.yaw)
                s.velocity.append((m.linear_velocity[0], m.linear_velocity[1]))
                s.omega.append(m.angular_velocity[2])
            elif rel == "sim/actors":
                s.actors_t.append(t)
                s.actors.append(decode(rec.payload, SimActors))
            elif rel == "safety/status":
                s.status_t.append(t)
                s.status.append(decode(rec.payload, SafetyStatus))
            elif rel == "cmd/ref":
                s.ref_t.append(t)
                s.ref.append(decode(rec.payload, VelocityCommand))
            elif rel == "cmd/safe":
                s.safe_t.append(t)
                s.safe.append(decode(rec.payload, VelocityCommand))
            elif rel == "map/esdf":
                s.esdf_t.append(t)
                s.esdf_stamp.append((decode(rec.payload, EsdfGrid).header.stamp_ns - first) / 1e9)
            elif rel.startswith("status/"):
                ns = decode(rec.payload, NodeStatus)
                s.node_status[rel.split("/", 1)[1]] = ns
                for k, v in ns.extra.items():
                    s.node_extra[ns.service][k].append(v)
        except DecodeError:
            s.counts["invalid:" + rel] += 1
    s.duration_s = (last - (first or last)) / 1e9
    if first is not None:
        _load_stamps(mcap_path, root, first, s)
    return s


def _load_stamps(mcap_path: str | Path, root: str, t0_ns: int, s: Streams) -> None:
    """(receive time, header stamp) of the ``STAGES`` keys: the recorder writes the header stamp as
    each message's MCAP ``publish_time``, raw or as a Foxglove view (``recorder.mcap_io``), so
    images and pointmaps need no decoding here."""
    seen_raw: set[str] = set()
    for _schema, channel, msg in iter_mcap(mcap_path):
        key = raw_key(channel)
        if key is not None:
            seen_raw.add(key)
        elif channel.topic in seen_raw:
            continue  # the view of a key also kept raw: counted once
        else:
            key = channel.topic
        rel = key[len(root) + 1:] if key.startswith(root + "/") else key
        if rel in STAGES and msg.publish_time != msg.log_time:  # equal: no stamp in the header
            s.stamped[rel].append(((msg.log_time - t0_ns) / 1e9, (msg.publish_time - t0_ns) / 1e9))


def fmt(v: Any, unit: str = "", digits: int = 2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v:.{digits}f}{unit}"


def _scene_objects() -> dict[str, Any]:
    """Ground truth: every object of the demo scene but floor and ceiling, plus the unseen ball."""
    return scene_objects(scenario(), [UNSEEN])


def _clearances(cfg: DemoConfig, t: np.ndarray, xy: np.ndarray, placed_at: float) -> dict[str, np.ndarray]:
    """Clearance to every object along the trajectory, and ``"all"``: the minimum over them.
    The unseen ball counts only from the moment it was placed."""

    objs = _scene_objects()
    scenes = {name: Scene([o]) for name, o in objs.items()}
    clear = clearance_series(lambda name, ts: scenes[name].at(ts), list(objs), t, xy, cfg.robot_radius,
                             t_sim0=float(t[0]))
    clear[UNSEEN["name"]] = np.where(t >= placed_at, clear[UNSEEN["name"]], np.inf)
    clear["all"] = np.min(np.vstack([clear[n] for n in objs]), axis=0)
    return clear


def make_report(cfg: DemoConfig, console: Console) -> dict:
    root = f"rf/{cfg.robot}"
    st = load_streams(latest_recording(cfg.out), root)  # a re-run in the same folder records beside the last
    t0 = st.t0_ns / 1e9
    ph = {k: v - t0 for k, v in cfg.phases.items()}
    t = np.asarray(st.state_t)
    xy = np.asarray(st.xy).reshape(-1, 2)
    summary: dict = {"duration_s": st.duration_s, "phases_s": ph}
    if t.size == 0:
        console.print("[red]no robot state was recorded[/red]")
        summary["collisions"] = -1
        return summary
    clear = _clearances(cfg, t, xy, ph.get("unseen_obstacle_placed", np.inf))
    status_t = np.asarray(st.status_t)
    # an intervention is the filter changing the command to stay safe, not a fail-safe brake
    inter = np.asarray([is_intervention(x) for x in st.status], dtype=bool)
    # -- teleop, per class -----------------------------------------------------------------------
    tele = (ph.get("teleop_start", 0.0), ph.get("teleop_end", 0.0))
    per_class = {}
    for obj, _x, _y in TELEOP_TARGETS:
        others = [o for o, *_ in TELEOP_TARGETS if o != obj]
        nearest = np.all([clear[obj] <= clear[o] for o in others], axis=0) if others else np.ones(len(t), bool)
        sel = (t >= tele[0]) & (t <= tele[1]) & nearest
        if not sel.any():
            per_class[TRACKED[obj]] = {"first_intervention_m": None, "min_clearance_m": None}
            continue
        window = (float(t[sel][0]), float(t[sel][-1]))
        tfi = first_intervention(status_t, inter, window)
        per_class[TRACKED[obj]] = {
            "first_intervention_m": None if tfi is None else distance_at(tfi, t, clear[obj]),
            "min_clearance_m": float(np.min(clear[obj][sel])),
        }
    # -- navigation ---------------------------------------------------------------------------------
    nav = (ph.get("navigation_start", 0.0), ph.get("navigation_end", ph.get("navigation_timeout", 0.0)))
    nsel = (t >= nav[0]) & (t <= nav[1])
    loop = np.asarray(LOOP)
    # deviation from the loop once the robot has joined it at the first waypoint
    joined = nsel & (np.cumsum(nsel & (np.linalg.norm(xy - loop[0], axis=1) < 0.3)) > 0)
    dev = float(polyline_distance(xy[joined], loop).max()) if joined.any() else None
    unseen_min = float(np.min(clear["unseen_ball"][nsel & (t >= ph.get("unseen_obstacle_placed", np.inf))])) \
        if (nsel & (t >= ph.get("unseen_obstacle_placed", np.inf))).any() else None
    navigation = {"completed": "navigation_end" in ph, "max_deviation_m": dev,
                  "min_clearance_m": float(np.min(clear["all"][nsel])) if nsel.any() else None,
                  "unseen_obstacle_min_clearance_m": unseen_min}
    # -- system numbers ------------------------------------------------------------------------------
    rates = {k: v / max(st.duration_s, 1e-9) for k, v in sorted(st.counts.items())
             if not k.startswith(("status/", "invalid:"))}
    ages = [x.esdf_age_ms for x in st.status if x.esdf_age_ms >= 0]
    solve = [x.solve_us for x in st.status if x.fallback is None]
    up = ph.get("services_alive", -np.inf)
    latency = command_latency_ms(st.ref_t, st.safe_t, since=up)
    fallbacks: dict[str, int] = {}
    for x in st.status:
        if x.fallback:
            fallbacks[x.fallback] = fallbacks.get(x.fallback, 0) + 1
    summary.update({
        "teleop": per_class, "navigation": navigation,
        "collisions": collisions(clear["all"]), "min_clearance_m": float(np.min(clear["all"])),
        "min_clearance_per_object_m": {n: float(np.min(v)) for n, v in clear.items()
                                       if n != "all" and np.isfinite(np.min(v))},
        "rates_hz": rates, "filter_step_us": timing_stats(solve),
        "command_latency_ms": timing_stats(latency), "fallbacks": fallbacks,
        "commands_before_up": sum(1 for x in st.ref_t if x < up),
        "robot_radius_m": cfg.robot_radius,
    })
    summary["people"] = people_summary(st, (ph.get("walker_crossing", nav[0]), nav[1]))
    # camera_to_cmd_safe_ms, esdf_content_age_ms, esdf_arrival_age_ms, esdf_age_ms, stages, work_ms
    summary.update(latency_summary(st.stamped, st.safe_t, ages, st.node_extra))
    _print(summary, console)
    try:
        _plots(cfg, st, t, clear, ph)
        summary["plots"] = ["teleop.png", "navigation.png"]
    except Exception as exc:  # a plot must never lose the numbers
        console.print(f"[yellow]plots skipped: {exc}[/yellow]")
    return summary


def people_summary(st: Streams, window: tuple[float, float]) -> dict[str, Any]:
    """The walking people against the robot over the whole run (clearance, contacts) and, within
    ``window`` (the crossing, to the end of navigation), the ghost time (``people`` module)."""
    from riskfield.protocol import ade20k

    t = np.asarray(st.state_t)
    out: dict[str, Any] = {"walkers": [], "min_clearance_m": None, "at_fault_contacts": 0, "person_contacts": 0,
                           "ghost_time_s": None, "ghost_censored": False}
    tracks: dict[str, list[tuple[float, Any]]] = {}
    for ta, msg in zip(st.actors_t, st.actors, strict=True):
        for a in msg.actors:
            if a.label == ade20k.index("person"):
                tracks.setdefault(a.name, []).append((ta, a))
    if not tracks or t.size == 0:
        return out
    xy, yaw = np.asarray(st.xy).reshape(-1, 2), np.asarray(st.yaw)
    vel, omega = np.asarray(st.velocity).reshape(-1, 2), np.asarray(st.omega)
    centres, gaps, total = [], [], P.Contacts()
    per: dict[str, float] = {}
    for name, items in tracks.items():
        tr = P.Track(np.array([a for a, _ in items]), np.array([m.position[:2] for _, m in items]),
                     radius=items[-1][1].radius)
        c = tr.at(t)
        gap, point = P.rectangle_gap(xy, yaw, c, tr.radius)
        gap = np.where(tr.present(t), gap, np.inf)
        total = total + P.contacts(gap, P.approach_speed(xy, vel, omega, point, c))
        centres.append(c)
        gaps.append(gap)
        per[name] = float(gap.min())
    ratio, valid = P.command_ratio(t, np.asarray(st.ref_t), np.array([c.linear[0] for c in st.ref]),
                                   np.asarray(st.safe_t), np.array([c.linear[0] for c in st.safe]))
    status_t = np.asarray(st.status_t)
    i = np.searchsorted(status_t, t, side="right") - 1
    brakes = np.array([x.fallback is not None for x in st.status] or [False])
    braking = np.where(i >= 0, brakes[np.clip(i, 0, len(brakes) - 1)], False)
    sel = (t >= window[0]) & (t <= window[1])
    ghost = P.ghost_time(t[sel], ratio[sel], valid[sel], P.relevant(xy, yaw, centres, gaps)[sel], braking[sel])
    out.update(walkers=sorted(per), min_clearance_per_person_m=per, min_clearance_m=min(per.values()),
               at_fault_contacts=total.at_fault_samples, person_contacts=total.person_samples,
               ghost_time_s=float(ghost.time_s), ghost_censored=bool(ghost.censored))
    return out


def _print(summary: dict, console: Console) -> None:
    f = fmt
    t1 = Table(title="Teleoperation (paper: ball 0.36 / 0.14 m, dog 0.56 / 0.41 m)")
    for col in ("class", "first intervention (m)", "min clearance (m)"):
        t1.add_column(col)
    for name, row in summary["teleop"].items():
        t1.add_row(name, f(row["first_intervention_m"]), f(row["min_clearance_m"]))
    nav = summary["navigation"]
    t2 = Table(title="Navigation loop with an unseen obstacle")
    for col in ("completed", "max deviation (m)", "min clearance (m)", "unseen obstacle clearance (m)"):
        t2.add_column(col)
    t2.add_row(str(nav["completed"]), f(nav["max_deviation_m"]), f(nav["min_clearance_m"]),
               f(nav["unseen_obstacle_min_clearance_m"]))
    t3 = Table(title="System")
    t3.add_column("measure")
    t3.add_column("value")
    t3.add_row("collisions (episodes of clearance < 0)", str(summary["collisions"]))
    t3.add_row("minimum clearance over the run", f(summary["min_clearance_m"], " m"))
    ppl = summary.get("people") or {}
    if ppl.get("walkers"):
        t3.add_row("people: min clearance (LIMO rectangle ↔ person)", f(ppl["min_clearance_m"], " m"))
        t3.add_row("people: contacts at fault / the person's (samples)",
                   f"{ppl['at_fault_contacts']} / {ppl['person_contacts']}")
        t3.add_row("people: ghost time after the crossing",
                   f(ppl["ghost_time_s"], " s", 1) + (" (to the end)" if ppl["ghost_censored"] else ""))
    for key in ("camera/image", "perception/frame", "map/esdf", "state", "cmd/ref", "cmd/safe"):
        t3.add_row(f"rate {key}", f(summary["rates_hz"].get(key), " Hz", 1))
    for key, unit, label in (("esdf_age_ms", " ms", "ESDF content age at the filter (its status)"),
                             ("esdf_content_age_ms", " ms", "ESDF content age (camera stamp) at cmd/safe"),
                             ("esdf_arrival_age_ms", " ms", "ESDF arrival age at cmd/safe"),
                             ("camera_to_cmd_safe_ms", " ms", "camera frame → first cmd/safe using it"),
                             ("filter_step_us", " µs", "filter step (field + QP)"),
                             ("command_latency_ms", " ms", "cmd/ref → cmd/safe latency, once the stack is up")):
        s = summary[key]
        t3.add_row(f"{label} median / p99", "–" if s is None else f"{f(s['median'], unit)} / {f(s['p99'], unit)}")
    t3.add_row("cmd/ref sent before the stack was up (not timed)", str(summary.get("commands_before_up", 0)))
    t3.add_row("braking reasons", ", ".join(f"{k}: {v}" for k, v in summary["fallbacks"].items()) or "none")
    out = Console()
    out.print(t1)
    out.print(t2)
    out.print(t3)
    if "stages" in summary:
        out.print(latency_table(summary))


def _plots(cfg: DemoConfig, st: Streams, t: np.ndarray, clear: dict, ph: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref_t, safe_t = np.asarray(st.ref_t), np.asarray(st.safe_t)
    ref = np.asarray([(c.linear[0], c.angular[2]) for c in st.ref]).reshape(-1, 2)
    safe = np.asarray([(c.linear[0], c.angular[2]) for c in st.safe]).reshape(-1, 2)
    tele = (ph.get("teleop_start", 0.0), ph.get("teleop_end", t[-1]))
    fig, axes = plt.subplots(len(TELEOP_TARGETS), 3, figsize=(13, 3.2 * len(TELEOP_TARGETS)), squeeze=False)
    for row, (obj, _x, _y) in enumerate(TELEOP_TARGETS):
        sel = (t >= tele[0]) & (t <= tele[1])
        ax = axes[row]
        ax[0].plot(t[sel], clear[obj][sel], color="k")
        ax[0].axhline(0, color="r", lw=0.8)
        ax[0].set_ylabel(f"{TRACKED[obj]}\nclearance (m)")
        for k, (label, unit) in enumerate((("v", "m/s"), ("ω", "rad/s"))):
            rs = (ref_t >= tele[0]) & (ref_t <= tele[1])
            ss = (safe_t >= tele[0]) & (safe_t <= tele[1])
            ax[k + 1].plot(ref_t[rs], ref[rs, k], label="reference", color="tab:blue", alpha=0.7)
            ax[k + 1].plot(safe_t[ss], safe[ss, k], label="safe", color="tab:red")
            ax[k + 1].set_ylabel(f"{label} ({unit})")
        ax[1].legend(loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle("Teleoperation with semantic CBF filtering (cf. the paper's Fig. 5)")
    fig.tight_layout()
    fig.savefig(cfg.out / "teleop.png", dpi=110)
    plt.close(fig)

    xy = np.asarray(st.xy).reshape(-1, 2)
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for obj in _scene_objects().values():
        if obj.name == UNSEEN["name"]:
            continue
        v = np.asarray(obj.world_mesh(0.0)[0])
        ax.fill(*_hull(v[:, :2]).T, alpha=0.35)
        if obj.class_name != "wall":
            ax.annotate(obj.name, v[:, :2].mean(0), fontsize=7, ha="center")
    ax.plot(*np.asarray(LOOP + LOOP[:1]).T, "k--", lw=0.8, label="waypoint loop")
    ax.plot(xy[:, 0], xy[:, 1], color="tab:blue", lw=1.2, label="robot")
    ux, uy = UNSEEN["position"]
    ax.add_patch(plt.Circle((ux, uy), 0.12, color="tab:orange", label="unseen obstacle"))
    ax.set_aspect("equal")
    ax.legend(loc="lower left", fontsize=8)
    ax.set_title("Overhead view: teleop then navigation (cf. the paper's Fig. 6)")
    fig.tight_layout()
    fig.savefig(cfg.out / "navigation.png", dpi=110)
    plt.close(fig)


def _hull(p: np.ndarray) -> np.ndarray:
    """Convex hull (monotone chain) of 2-D points, closed."""
    pts = sorted(set(map(tuple, np.round(p, 4))))
    if len(pts) < 3:
        return np.asarray(pts + pts[:1])

    def half(points):
        h: list = []
        for q in points:
            while len(h) >= 2 and np.cross(np.subtract(h[-1], h[-2]), np.subtract(q, h[-2])) <= 0:
                h.pop()
            h.append(q)
        return h

    lower, upper = half(pts), half(pts[::-1])
    hull = lower[:-1] + upper[:-1]
    return np.asarray(hull + hull[:1])
