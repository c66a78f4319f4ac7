"""``riskfield bench crowd``: people walking into a robot's way, through the full service stack.

A LIMO is driven straight ahead at 0.5 m/s (a constant ``cmd/ref``, as an operator would) down a
12 × 6 m room while people cross its lane, come head-on and stop in it, overtake it and cut in,
or walk in, stop and turn back (``scenarios.crowd_case``: 4 kinds × 2 walking speeds × 3 seeds by
default; seeds ≥ 1 add a second person passing beside the lane). Every case is a conflict: on the
nominal drive the robot would touch the person, and the person is in the camera's view at least
1 s before (``scenarios.crowd_nominal``). Simulator → perception (``gt`` relay or the FM-like
``sim`` backend) → mapping → safety filter → simulator, separate processes on a loopback router;
the simulator starts over between cases (``sim/reset``), mapping and perception are restarted so
no case sees the previous one's map.

Per case and in total (``riskfield.experiments.people`` defines each, from the simulator's
ground truth on ``sim/actors``): at-fault contacts (the LIMO rectangle overlapping a person's
cylinder while its nearest point moves towards them > 0.05 m/s) and the person's contacts (robot
stopped or retreating); the minimum clearance to people; progress (distance driven / the
reference's); ghost time (after people leave the robot's way, how long the command stays below
80 % of the reference; p95 over the cases); the map's lag behind the truth (when the map's person
cells were true). Outputs ``summary.json``, ``tables.md``, ``crowd_<variant>.png`` (overhead tracks).

Variants: ``motion`` (the filter's defaults) and ``static``, the static-barrier baseline (the
filter's ``object_motion`` off). A filter without the ``object_motion`` setting *is* the static
barrier: then only ``static`` runs, and the summary says so (``baseline_is_static_only``), rather
than report two runs of one filter as a difference.
"""

from __future__ import annotations

import json
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
import yaml
from rich.console import Console
from rich.table import Table

from riskfield.experiments import people as P
from riskfield.experiments.scenarios import (
    CROWD_CAMERA_X,
    CROWD_HFOV_DEG,
    CROWD_KINDS,
    CROWD_ROOM,
    CROWD_SPEEDS,
    crowd_cases,
)
from riskfield.experiments.stack import FAST_FILTER, Stack, perception_args, publish, recording
from riskfield.experiments.tables import write_json
from riskfield.options import grouped
from riskfield.protocol import (
    EsdfGrid,
    RiskConfig,
    RobotState,
    SafetyStatus,
    SimActors,
    TrackedObjects,
    VelocityCommand,
    ade20k,
)
from riskfield.services.safety_filter.config import MotionParams

app = typer.Typer(add_completion=False)

#: cmd/ref period (s): an operator's stick at 20 Hz
REF_PERIOD = 0.05
#: s to wait for the first map after mapping restarts
MAP_TIMEOUT = 30.0


def object_motion_available() -> bool:
    """Whether the safety filter has the ``object_motion`` setting (∂h/∂t from ``map/objects``)."""
    from riskfield.services.safety_filter.settings import FilterSettings

    return "object_motion" in FilterSettings.model_fields


def variant_args(available: bool) -> dict[str, list[str]]:
    """Variant name → the filter's arguments. Without ``object_motion`` the filter is the static
    barrier, the only variant there is."""
    if not available:
        return {"static": list(FAST_FILTER)}
    return {"motion": [*FAST_FILTER, "--set", "object_motion=true"],
            "static": [*FAST_FILTER, "--set", "object_motion=false"],
            "evade": [*FAST_FILTER, "--set", "object_motion=true", "--set", "evade=true"]}


# -- one case --------------------------------------------------------------------------------------

def _esdf_cells(grid: EsdfGrid, group: int) -> np.ndarray:
    """Floor (x, y) of the cells inside the inflated obstacle set of risk ``group`` (2-D slice or the
    lowest layer of a 3-D grid)."""
    d, g = grid.distance[..., 0], grid.risk_group[..., 0]
    i, j = np.nonzero((d < 0) & (g == group))
    return np.column_stack([grid.origin[0] + grid.voxel_size * i, grid.origin[1] + grid.voxel_size * j])


def case_metrics(case: dict[str, Any], states: list[RobotState], refs: list[VelocityCommand],
                 safes: list[VelocityCommand], actors: list[SimActors], esdfs: list[tuple[float, EsdfGrid]],
                 t0: float, status: list[SafetyStatus] = (), objects: list[TrackedObjects] = ()) -> dict[str, Any]:
    """The metrics of one case from what was recorded (stamps in wall-clock seconds; ``esdfs`` with
    their wall-clock receive times; ``t0`` the drive's start; ``status`` the filter's, for its
    fail-safe brakes; ``objects`` the mapper's tracks, for the tracker's accuracy). Pure: the unit
    tests call it."""
    if not states:
        return {"name": case["name"], "error": "no robot state recorded"}
    t = np.array([s.header.stamp_ns for s in states]) / 1e9
    order = np.argsort(t)
    states = [states[k] for k in order]
    t = t[order]
    xy = np.array([s.position[:2] for s in states])
    yaw = np.array([s.yaw for s in states])
    vel = np.array([s.linear_velocity[:2] for s in states])
    omega = np.array([s.angular_velocity[2] for s in states])
    tracks: dict[str, P.Track] = {}
    by_name: dict[str, list[tuple[float, Any]]] = {}
    for msg in actors:
        for a in msg.actors:
            if a.label == ade20k.index("person"):
                by_name.setdefault(a.name, []).append((msg.header.stamp_ns / 1e9, a))
    for name, items in by_name.items():
        tracks[name] = P.Track(np.array([s for s, _ in items]), np.array([a.position[:2] for _, a in items]),
                               np.array([a.velocity[:2] for _, a in items]), items[-1][1].radius)
    total = P.Contacts()
    per_person: dict[str, dict[str, Any]] = {}
    centres, gaps = [], []
    for name, tr in tracks.items():
        present = tr.present(t)
        c = tr.at(t)
        gap, point = P.rectangle_gap(xy, yaw, c, tr.radius)
        gap = np.where(present, gap, np.inf)
        approach = P.approach_speed(xy, vel, omega, point, c)
        con = P.contacts(gap, approach)
        total = total + con
        centres.append(c)
        gaps.append(gap)
        per_person[name] = {"min_clearance_m": float(gap.min()), **con.__dict__}
    ratio, valid = P.command_ratio(
        t, np.array([r.header.stamp_ns for r in refs]) / 1e9, np.array([r.linear[0] for r in refs]),
        np.array([s.header.stamp_ns for s in safes]) / 1e9, np.array([s.linear[0] for s in safes]))
    rel = P.relevant(xy, yaw, centres, gaps) if centres else np.zeros(len(t), bool)
    drive = t >= t0
    braking = np.zeros(len(t), bool)
    if len(status):
        st_t = np.array([x.header.stamp_ns for x in status]) / 1e9
        st_order = np.argsort(st_t)
        st_brake = np.array([status[i].fallback is not None for i in st_order])
        i = np.searchsorted(st_t[st_order], t, side="right") - 1
        braking = np.where(i >= 0, st_brake[np.clip(i, 0, None)], False)
    ghost = P.ghost_time(t[drive], ratio[drive], valid[drive], rel[drive], braking[drive])
    heading = np.array([math.cos(yaw[0]), math.sin(yaw[0])])
    driven = float((xy[-1] - xy[0]) @ heading)
    nominal = case["v_ref"] * max(float(t[-1] - t0), 1e-9)
    lag = map_lag(t, xy, yaw, tracks, esdfs)
    person = ade20k.index("person")
    observed = [(m.header.stamp_ns / 1e9 - o.age_ms / 1e3, o.tracked_ms, np.array(o.position[:2]),
                 np.array(o.velocity[:2])) for m in objects for o in m.objects if o.label == person]
    tracker = P.tracker_errors(observed, list(tracks.values()), MotionParams().object_young_ms)
    min_clear = min((p["min_clearance_m"] for p in per_person.values()), default=math.inf)
    return {"name": case["name"], "kind": case["kind"], "speed": case["speed"], "seed": case["seed"],
            "walkers": len(tracks), "at_fault_contacts": total.at_fault_samples,
            "at_fault_episodes": total.at_fault_episodes, "person_contacts": total.person_samples,
            "person_episodes": total.person_episodes, "max_at_fault_speed": total.max_at_fault_speed,
            "min_clearance_m": min_clear, "progress": driven / nominal, "ghost_time_s": ghost.time_s,
            "ghost_censored": ghost.censored, "ghost_holds_s": ghost.holds, **lag, "people": per_person,
            "path": xy.tolist(), "tracks": {n: tr.xy.tolist() for n, tr in tracks.items()},
            "contacts_xy": _contact_points(xy, gaps, centres), "tracker": tracker.summary(),
            "tracker_errors": tracker.__dict__}


def _contact_points(xy: np.ndarray, gaps: list[np.ndarray], centres: list[np.ndarray]) -> list[list[float]]:
    out = []
    for g in gaps:
        hit = np.flatnonzero(g < 0)
        if hit.size:
            out.append(xy[hit[0]].tolist())
    return out


def map_lag(t: np.ndarray, xy: np.ndarray, yaw: np.ndarray, tracks: dict[str, P.Track],
            esdfs: list[tuple[float, EsdfGrid]]) -> dict[str, Any]:
    """The map's lag behind the truth for walking people in view (``people`` module doc), the share
    of maps that show a person in view near where they are, and the lags themselves."""
    person = ade20k.index("person")
    lut = RiskConfig().label_to_group()
    names = [g.name for g in RiskConfig().groups]
    lags, shown, seen = [], 0, 0
    for received, grid in esdfs:
        s = grid.header.stamp_ns / 1e9
        group_name = names[int(lut[person]) - 1] if lut[person] else None
        if group_name not in grid.groups:
            continue
        cells = _esdf_cells(grid, grid.groups.index(group_name) + 1)
        pose_xy = np.array([[np.interp(s, t, xy[:, 0]), np.interp(s, t, xy[:, 1])]])
        pose_yaw = np.array([np.interp(s, t, np.unwrap(yaw))])
        for tr in tracks.values():
            if not tr.present(np.array([s]))[0]:
                continue
            here = tr.at(s)
            if not P.in_view(pose_xy, pose_yaw, here, tr.radius, CROWD_HFOV_DEG, CROWD_CAMERA_X, 6.0)[0]:
                continue
            seen += 1
            c = P.map_centroid(cells, here[0], within=1.2)
            if c is None:
                continue
            shown += int(np.hypot(*(c - here[0])) <= 0.5)
            if tr.speed_at(np.array([s]))[0] > 0.3:
                tau, resid = P.best_shift(tr, s, c)
                if resid <= 0.35:
                    lags.append(received - s + tau)
    return {"map_lag_s": lags, "map_lag_median_s": P.percentile(lags, 50), "map_lag_p95_s": P.percentile(lags, 95),
            "map_shows_person": (shown / seen) if seen else None, "maps_with_person_in_view": seen}


# -- the stack ---------------------------------------------------------------------------------------

class _Esdfs:
    """The ESDFs with their wall-clock receive times (the stack's recorder keeps monotonic ones)."""

    def __init__(self, session: Any, key: str):
        from riskfield.protocol import decode

        self.items: list[tuple[float, EsdfGrid]] = []
        self._lock = threading.Lock()

        def on(sample: Any) -> None:
            received = time.time()
            try:
                grid = decode(sample.payload.to_bytes(), EsdfGrid)
            except Exception:
                return
            with self._lock:
                self.items.append((received, grid))

        self._sub = session.declare_subscriber(key, on)

    def take(self) -> list[tuple[float, EsdfGrid]]:
        with self._lock:
            out, self.items = self.items, []
        return out

    def close(self) -> None:
        self._sub.undeclare()


def _stop(stack: Stack, labels: list[str]) -> None:
    """Stop services together (each waits for its process to end)."""
    with ThreadPoolExecutor(len(labels)) as pool:
        list(pool.map(stack.stop, labels))


def _start(stack: Stack, specs: list[tuple[str, str, list[str]]]) -> None:
    """Start services together (their start-ups overlap) and wait until all are alive."""
    for label, service, args in specs:
        stack.start(label, service, args, wait=False)
    if not stack.runner.wait_ready(stack.session, [s[0] for s in specs], 120):
        raise RuntimeError(f"{', '.join(s[0] for s in specs)} did not come up")


def run_case(stack: Stack, case: dict[str, Any], pipeline: list[tuple[str, str, list[str]]], rec: Any,
             esdfs: _Esdfs) -> dict[str, Any]:
    k = stack.keys
    t_case = time.perf_counter()
    _stop(stack, [label for label, _, _ in pipeline])
    publish(stack.session, k.sim_reset, b"")
    _start(stack, pipeline)
    # Ready once the filter holds a map built after the restart (a brake on a missing map is not
    # what a case measures), plus a second of frames into it.
    rec.clear()
    esdfs.take()
    deadline = time.monotonic() + MAP_TIMEOUT
    while time.monotonic() < deadline and not any(s.esdf_age_ms >= 0 for _, s in rec.snapshot("status")[-5:]):
        time.sleep(0.05)
    time.sleep(1.0)
    rec.clear()
    esdfs.take()
    for spec in case["walkers"]:
        publish(stack.session, k.sim_spawn, json.dumps(spec).encode())
    t0 = time.time()
    sent: list[VelocityCommand] = []
    next_t = time.monotonic()
    end = next_t + case["drive_s"]
    while time.monotonic() < end:
        sent.append(VelocityCommand(linear=(case["v_ref"], 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="crowd"))
        publish(stack.session, k.cmd_ref, sent[-1])
        next_t += REF_PERIOD
        time.sleep(max(0.0, next_t - time.monotonic()))
    row = case_metrics(case, [m for _, m in rec.snapshot("state")], sent,
                       [m for _, m in rec.snapshot("safe")], [m for _, m in rec.snapshot("actors")], esdfs.take(),
                       t0, [m for _, m in rec.snapshot("status")], [m for _, m in rec.snapshot("objects")])
    reasons: dict[str, int] = {}
    for _, st in rec.snapshot("status"):
        if st.fallback is not None:
            reasons[st.fallback] = reasons.get(st.fallback, 0) + 1
    row["brakes"] = reasons
    ages = [st.esdf_age_ms for _, st in rec.snapshot("status") if st.esdf_age_ms >= 0]
    row["esdf_age_ms_p50"] = P.percentile(ages, 50)
    row["esdf_age_ms_p95"] = P.percentile(ages, 95)
    row["case_wall_s"] = time.perf_counter() - t_case
    return row


def run_bench(cases: list[dict[str, Any]], perception: str, variants: dict[str, list[str]], out: Path,
              console: Console | None = None) -> dict[str, list[dict[str, Any]]]:
    """Every case under every variant, on one stack; rows per variant."""
    out.mkdir(parents=True, exist_ok=True)
    room = out / "crowd_room.yaml"
    room.write_text(yaml.safe_dump(CROWD_ROOM))
    service, args = perception_args(perception)
    pipeline = [("perception", service, args), ("mapping", "mapping", ["--set", "esdf_rate_hz=10"])]
    results: dict[str, list[dict[str, Any]]] = {}
    with Stack(robot="crowd") as stack:
        k = stack.keys
        stack.start("sim", "simulator", ["--set", f"scenario={room}", "--set", "camera_hz=10"])
        keys = {"state": (k.state, RobotState), "safe": (k.cmd_safe, VelocityCommand),
                "status": (k.safety_status, SafetyStatus), "actors": (k.sim_actors, SimActors),
                "objects": (k.objects, TrackedObjects)}
        esdfs = _Esdfs(stack.session, k.esdf)
        try:
            with recording(stack.session, keys) as rec:
                for variant, filter_args in variants.items():
                    stack.stop("filter")
                    stack.start("filter", "safety-filter", filter_args)
                    rows = results[variant] = []
                    for case in cases:
                        row = run_case(stack, case, pipeline, rec, esdfs)
                        rows.append(row)
                        if console is not None:
                            console.print(f"{variant:6s} {row['name']:22s} at-fault {row['at_fault_contacts']:3d} "
                                          f"person {row['person_contacts']:3d} clearance "
                                          f"{row['min_clearance_m']:+.2f} m ghost {row['ghost_time_s']:.1f} s "
                                          f"progress {row['progress']:.2f} ({row['case_wall_s']:.0f} s)")
        finally:
            esdfs.close()
    return results


# -- summary -----------------------------------------------------------------------------------------

def totals(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The variant's totals over its cases."""
    ok = [r for r in rows if "error" not in r]
    lags = [x for r in ok for x in r["map_lag_s"]]
    shown = [r["map_shows_person"] for r in ok if r["map_shows_person"] is not None]
    return {
        "cases": len(rows), "cases_failed": len(rows) - len(ok),
        "at_fault_contacts": sum(r["at_fault_contacts"] for r in ok),
        "at_fault_episodes": sum(r["at_fault_episodes"] for r in ok),
        "cases_with_at_fault_contact": sum(r["at_fault_contacts"] > 0 for r in ok),
        "person_contacts": sum(r["person_contacts"] for r in ok),
        "person_episodes": sum(r["person_episodes"] for r in ok),
        "min_clearance_m": min((r["min_clearance_m"] for r in ok if r["min_clearance_m"] is not None), default=None),
        "progress_mean": float(np.mean([r["progress"] for r in ok])) if ok else None,
        "ghost_time_p95_s": P.percentile([r["ghost_time_s"] for r in ok], 95),
        "ghost_time_max_s": max((r["ghost_time_s"] for r in ok), default=None),
        "ghost_censored_cases": sum(bool(r["ghost_censored"]) for r in ok),
        "map_lag_median_s": P.percentile(lags, 50), "map_lag_p95_s": P.percentile(lags, 95),
        "map_shows_person_mean": float(np.mean(shown)) if shown else None,
        "fail_safe_brake_steps": sum(sum(r.get("brakes", {}).values()) for r in ok),
        "stale_map_brake_steps": sum(r.get("brakes", {}).get("stale_map", 0) for r in ok),
        "esdf_age_ms_p50_median": P.percentile([r["esdf_age_ms_p50"] for r in ok if r.get("esdf_age_ms_p50")], 50),
        "tracker": sum((P.TrackerErrors(**r["tracker_errors"]) for r in ok if "tracker_errors" in r),
                       P.TrackerErrors()).summary(),
        "case_wall_median_s": float(np.median([r["case_wall_s"] for r in rows if "case_wall_s" in r]))
        if any("case_wall_s" in r for r in rows) else None,
    }


def _f(v: Any, digits: int = 2, unit: str = "") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v:.{digits}f}{unit}"


def markdown(summary: dict[str, Any]) -> str:
    lines = [f"# riskfield bench crowd — perception `{summary['perception']}`", ""]
    if summary["baseline_is_static_only"]:
        lines += ["The safety filter has no `object_motion` setting yet: it is the static barrier, so only the "
                  "`static` variant ran (a second run of the same filter would be no comparison).", ""]
    lines += ["| Variant | Cases | At-fault contacts (samples / episodes / cases) | Person's contacts | "
              "Min clearance (m) | Progress | Ghost time p95 / max (s) | Map lag p50 / p95 (s) | "
              "Maps showing the person | Fail-safe brake steps (stale map) | ESDF age at the filter, p50 (ms) |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for v, tot in summary["totals"].items():
        lines.append(f"| {v} | {tot['cases']} | {tot['at_fault_contacts']} / {tot['at_fault_episodes']} / "
                     f"{tot['cases_with_at_fault_contact']} | {tot['person_contacts']} | "
                     f"{_f(tot['min_clearance_m'])} | {_f(tot['progress_mean'])} | "
                     f"{_f(tot['ghost_time_p95_s'], 1)} / {_f(tot['ghost_time_max_s'], 1)} | "
                     f"{_f(tot['map_lag_median_s'])} / {_f(tot['map_lag_p95_s'])} | "
                     f"{_f(tot['map_shows_person_mean'])} | {tot['fail_safe_brake_steps']} "
                     f"({tot['stale_map_brake_steps']}) | {_f(tot['esdf_age_ms_p50_median'], 0)} |")
    for v, tot in summary["totals"].items():
        tk = tot.get("tracker") or {}
        if tk.get("matched"):
            lines += ["", f"Tracker accuracy ({v}): velocity error σ per axis {_f(tk['velocity_sigma_settled_m_s'])} "
                      f"m/s RMS, {_f(tk.get('velocity_sigma_robust_m_s'))} m/s from the median, over {tk['settled']} "
                      f"settled tracks ({_f(tk['velocity_sigma_all_m_s'])} RMS over all "
                      f"{tk['matched']}), |Δv| p50 / p95 {_f(tk['velocity_error_p50_m_s'])} / "
                      f"{_f(tk['velocity_error_p95_m_s'])} m/s, position error p50 / p95 "
                      f"{_f(tk['position_error_p50_m'])} / {_f(tk['position_error_p95_m'])} m, "
                      f"{tk['false_tracks']} false tracks."]
    for v, rows in summary["cases"].items():
        lines += ["", f"## {v}", "", "| Case | Walkers | At-fault (samples / max m/s) | Person's | Min clearance (m) "
                  "| Progress | Ghost (s) | Map lag p50 (s) | Maps showing | Brake steps | ESDF age p50 (ms) "
                  "| Wall (s) |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            if "error" in r:
                lines.append(f"| {r['name']} | {r['error']} |")
                continue
            lines.append(f"| {r['name']} | {r['walkers']} | {r['at_fault_contacts']} / "
                         f"{_f(r['max_at_fault_speed'])} | {r['person_contacts']} | {_f(r['min_clearance_m'])} | "
                         f"{_f(r['progress'])} | {_f(r['ghost_time_s'], 1)}{'+' if r['ghost_censored'] else ''} | "
                         f"{_f(r['map_lag_median_s'])} | {_f(r['map_shows_person'])} | "
                         f"{sum(r.get('brakes', {}).values())} | {_f(r.get('esdf_age_ms_p50'), 0)} | "
                         f"{_f(r['case_wall_s'], 0)} |")
    lines += ["", "Ghost `+`: the robot was still held back when the case ended (the time is a lower bound). Brake "
              "steps: the filter's fail-safe brakes (50 Hz steps; a map older than 0.4 s is refused as stale), whose "
              "time the ghost does not count."]
    return "\n".join(lines) + "\n"


def plot(out: Path, variant: str, rows: list[dict[str, Any]]) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = sorted({r["kind"] for r in rows if "kind" in r}, key=CROWD_KINDS.index)
    speeds = sorted({r["speed"] for r in rows if "speed" in r})
    fig, axes = plt.subplots(len(kinds), len(speeds), figsize=(6.5 * len(speeds), 2.9 * len(kinds)), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, kind in enumerate(kinds):
        for j, speed in enumerate(speeds):
            ax = axes[i, j]
            for n, r in enumerate(x for x in rows if x.get("kind") == kind and x.get("speed") == speed):
                col = colours[n % len(colours)]
                p = np.asarray(r["path"])
                ax.plot(p[:, 0], p[:, 1], color=col, lw=1.6, label=f"robot, seed {r['seed']}")
                for tr in r["tracks"].values():
                    q = np.asarray(tr)
                    ax.plot(q[:, 0], q[:, 1], color=col, lw=0.9, ls="--")
                    ax.plot(q[-1, 0], q[-1, 1], "o", color=col, ms=3)
                for c in r["contacts_xy"]:
                    ax.plot(c[0], c[1], "x", color="red" if r["at_fault_contacts"] else "orange", ms=8, mew=2)
            ax.set_xlim(-6, 6)
            ax.set_ylim(-3, 3)
            ax.set_aspect("equal")
            ax.set_title(f"{kind}, walkers at {speed:g} m/s", fontsize=9)
            ax.legend(fontsize=6, loc="lower right")
    fig.suptitle(f"crowd — {variant}: robot (solid), people (dashed, ● end), first contact "
                 "(red ×: at fault, orange: the person's)", fontsize=9)
    fig.tight_layout()
    path = out / f"crowd_{variant}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


@dataclass(frozen=True)
class CoreOptions:
    """The options of ``--mode core`` (:func:`core`)."""

    families: Annotated[str, typer.Option(help="core: comma-separated families (default: all).")] = ""
    episodes: Annotated[int, typer.Option(help="core: randomised episodes per family.", min=1)] = 100
    seed: Annotated[int, typer.Option(help="core: the first episode's seed (seeds seed … seed+episodes-1).")] = 0
    results: Annotated[Path | None, typer.Option(help="core: rewrite this RESULTS.md's 'Crowd families (core)' "
                                                 "section with the run's table.")] = None
    evade: Annotated[bool, typer.Option(
        help="core: the filter's opt-in evade (retreat into floor seen free).")] = False


@app.command()
@grouped
def crowd(
    perception: Annotated[str, typer.Option(help="gt or sim.")] = "sim",
    seeds: Annotated[str, typer.Option(help="Comma-separated seeds.")] = "0,1,2",
    kinds: Annotated[str, typer.Option(help=f"Comma-separated: {','.join(CROWD_KINDS)}.")] = ",".join(CROWD_KINDS),
    speeds: Annotated[str, typer.Option(help="Walking speeds (m/s, ≤ 1.5), comma-separated.")] = ",".join(
        f"{v:g}" for v in CROWD_SPEEDS),
    variants: Annotated[str, typer.Option(help="motion,static,evade (static: the static-barrier baseline; evade: "
                                          "motion with the opt-in retreat).")] = "motion,static",
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("bench_out/crowd"),
    mode: Annotated[str, typer.Option(help="stack: the full service stack (the cases above); core: the filter "
                                      "core in closed loop over the CrowdNav-style families.")] = "stack",
    core_run: CoreOptions = CoreOptions(),
) -> None:
    """People crossing, coming head-on, overtaking, stopping and turning in a robot's way."""
    console = Console()
    if mode == "core":
        c = core_run
        core(c.families, c.episodes, c.seed, out if out != Path("bench_out/crowd") else Path("bench_out/crowd_core"),
             c.results, console, c.evade)
        return
    if mode != "stack":
        raise typer.BadParameter("mode must be stack or core")
    if core_run.families:
        raise typer.BadParameter("--families runs in --mode core only (the stack mode runs the kinds)")
    if perception not in ("gt", "sim"):
        raise typer.BadParameter("perception must be gt or sim")
    try:
        cases = crowd_cases([k.strip() for k in kinds.split(",") if k.strip()],
                            [float(v) for v in speeds.split(",") if v.strip()],
                            [int(s) for s in seeds.split(",") if s.strip()])
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from exc
    available = object_motion_available()
    known = variant_args(True)
    wanted = [v.strip() for v in variants.split(",") if v.strip()]
    if not wanted or any(v not in known for v in wanted):
        raise typer.BadParameter(f"variants must be among {', '.join(known)}")
    runnable = variant_args(available)
    chosen = {v: runnable[v] for v in dict.fromkeys(v if available else "static" for v in wanted)}
    t_start = time.perf_counter()
    results = run_bench(cases, perception, chosen, out, console)
    wall = time.perf_counter() - t_start
    summary = {"benchmark": "crowd", "perception": perception, "wall_time_s": wall,
               "cases_per_variant": len(cases), "object_motion_available": available,
               "baseline_is_static_only": not available, "variants": list(chosen),
               "definitions": {"at_fault_speed_m_s": P.AT_FAULT_SPEED, "ghost_fraction": P.GHOST_FRACTION,
                               "relevant_gap_m": P.RELEVANT_GAP, "v_ref_m_s": cases[0]["v_ref"] if cases else None},
               "totals": {v: totals(rows) for v, rows in results.items()}, "cases": results}
    (out / "tables.md").write_text(markdown(summary))
    write_json(out / "summary.json", summary)
    for v, rows in results.items():
        plot(out, v, rows)
    table = Table("variant", "cases", "at-fault", "person's", "min clearance (m)", "progress", "ghost p95 (s)",
                  "map lag p50/p95 (s)")
    for v, tot in summary["totals"].items():
        table.add_row(v, str(tot["cases"]), str(tot["at_fault_contacts"]), str(tot["person_contacts"]),
                      _f(tot["min_clearance_m"]), _f(tot["progress_mean"]), _f(tot["ghost_time_p95_s"], 1),
                      f"{_f(tot['map_lag_median_s'])} / {_f(tot['map_lag_p95_s'])}")
    console.print(table)
    if not available:
        console.print("the filter has no object_motion setting: only the static barrier ran")
    console.print(f"wrote {out / 'tables.md'}, {out / 'summary.json'} and the plots ({wall:.0f} s, "
                  f"{wall / max(1, len(cases) * len(chosen)):.1f} s per case)")


def core(families: str, episodes: int, seed: int, out: Path, results: Path | None, console: Console,
         evade: bool = False) -> None:
    """``--mode core``: every family's episodes through the filter core (``crowd_core``)."""
    from riskfield.experiments import crowd_core as C
    from riskfield.services.safety_filter.config import FilterConfig
    from riskfield.services.safety_filter.filter import SafetyFilter

    chosen = [f.strip() for f in families.split(",") if f.strip()] or list(C.FAMILIES)
    unknown = [f for f in chosen if f not in C.FAMILIES]
    if unknown:
        raise typer.BadParameter(f"unknown families {unknown}: use {', '.join(C.FAMILIES)}")
    out.mkdir(parents=True, exist_ok=True)
    filt = SafetyFilter(FilterConfig(evade=evade))
    t0 = time.perf_counter()
    rows: dict[str, list[dict[str, Any]]] = {}
    fams: dict[str, Any] = {}
    for fam in chosen:
        rows[fam], wall = C.run_family(fam, episodes, seed, filt)
        fams[fam] = C.summarise(rows[fam], wall)
        s = fams[fam]
        console.print(f"{fam:13s} {episodes} episodes, {wall:.0f} s: at-fault {s['at_fault_contacts']}, static "
                      f"{s['static_contacts']}, idle {s['idle_displacement_max_m']:.2f} m, reverse "
                      f"{s['blind_reverse_max_m']:.2f} m, success {_f(s['success_rate'])}")
    command = f"riskfield bench crowd --mode core --episodes {episodes}" + (
        f" --families {','.join(chosen)}" if chosen != list(C.FAMILIES) else "") + (
        f" --seed {seed}" if seed else "") + (" --evade" if evade else "")
    summary = {"benchmark": "crowd", "mode": "core", "command": command, "evade": evade,
               "episodes_per_family": episodes,
               "first_seed": seed, "wall_time_s": time.perf_counter() - t0,
               "sim_time_s": sum(s["sim_s"] for s in fams.values()), "families": fams, "episodes": rows}
    (out / "tables.md").write_text(C.markdown(summary))
    write_json(out / "summary.json", summary)
    if results is not None:
        C.update_results(results, summary)
    console.print(C.table(summary))
    console.print(f"wrote {out / 'tables.md'} and {out / 'summary.json'} ({summary['wall_time_s']:.0f} s)")
