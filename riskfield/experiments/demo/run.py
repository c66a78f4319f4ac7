"""Orchestration of ``riskfield demo``: start the stack, drive the two experiments, report."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from rich.console import Console
from rich.table import Table

from riskfield.launcher import Launcher
from riskfield.protocol import ENCODING, Keys, NavGoal, NodeStatus, SafetyStatus, decode, encode
from riskfield.services.simulator.scenario import ObjectSpec, build_scene, load_scenario, object_from_spec
from riskfield.services.simulator.scene import Scene
from riskfield.testing import client_session, free_port, wait_alive, wait_until

from . import report as rp
from .scenario import LOOP, TELEOP_TARGETS, TRACKED, UNSEEN, navigation_waypoints, scenario

SERVICES = ["simulator", "perception", "mapping", "safety-filter", "navigator", "operator"]


@dataclass
class DemoConfig:
    out: Path = Path("out/demo")
    live: bool = False
    robot: str = "demo1"
    seed: int = 0
    teleop_push_s: float = 6.0
    laps: float = 1.5
    budget_s: float = 100.0  # the two experiments together, after start-up
    robot_radius: float = 0.15
    verbose: bool = False
    phases: dict[str, float] = field(default_factory=dict)


class Demo:
    def __init__(self, cfg: DemoConfig, console: Console | None = None):
        self.cfg = cfg
        self.console = console or Console(stderr=True, highlight=False)
        self.keys = Keys(robot=cfg.robot)
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.t0 = 0.0

    def _mark(self, name: str) -> None:
        self.cfg.phases[name] = time.time()
        self.console.print(f"[bold]{time.monotonic() - self.t0:6.1f} s[/bold]  {name.replace('_', ' ')}")

    def _launcher(self) -> Launcher:
        c, out = self.cfg, self.cfg.out
        common = ["--robot", c.robot]
        connect = ["--connect", self.endpoint, *common]
        targets = json.dumps([[n, x, y] for n, x, y in TELEOP_TARGETS])
        la = Launcher(log_path=out / "stack.log", echo=c.verbose, console=self.console)
        la.add("router", ["--listen", self.endpoint, *common])
        la.add("record", [*connect, "--set", f"out={out}"])
        la.add("simulator", [*connect, "--set", f"scenario={out / 'scenario.yaml'}"])
        la.add("perception", connect)
        la.add("mapping", connect)
        la.add("safety-filter", [*connect, "--set", f"robot_radius={c.robot_radius}"])
        la.add("navigator", connect)
        la.add("operator", [*connect, "--set", f"targets={targets}", "--set", f"seed={c.seed}",
                            "--set", f"push_s={c.teleop_push_s}"])
        if c.live:
            la.add("viewer", [*connect, "--set", "live=true", "--set", f"out={out}"])
        return la

    def run(self) -> int:
        c = self.cfg
        c.out.mkdir(parents=True, exist_ok=True)
        (c.out / "scenario.yaml").write_text(yaml.safe_dump(scenario(), sort_keys=False))
        self.t0 = time.monotonic()
        launcher = self._launcher()
        launcher.start()
        self._mark("stack_started")
        ok = False
        try:
            with client_session(self.endpoint, timeout_s=30) as s:
                ok = self._experiments(s, launcher)
        finally:
            launcher.stop()
            self._mark("stack_stopped")
        dead = [ch.name for ch in launcher.children if ch.proc is not None and ch.proc.returncode not in (0, -2)]
        if dead:
            self.console.print(f"[red]services ended badly: {', '.join(dead)} (see {c.out / 'stack.log'})[/red]")
        (c.out / "phases.json").write_text(json.dumps(c.phases, indent=2) + "\n")
        summary = make_report(c, self.console)
        summary["services_ended_badly"] = dead
        summary["experiments_completed"] = ok
        (c.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        return 0 if ok and not dead and summary["collisions"] == 0 else 1

    def _status(self, s, service: str, timeout: float = 3.0) -> NodeStatus | None:
        got: list[NodeStatus] = []
        sub = s.declare_subscriber(self.keys.status(service), lambda smp: got.append(decode(smp.payload.to_bytes())))
        wait_until(lambda: bool(got), timeout)
        sub.undeclare()
        return got[-1] if got else None

    def _experiments(self, s, launcher: Launcher) -> bool:
        c = self.cfg
        for name in ["router", "record", *SERVICES]:
            if not wait_alive(s, self.keys.alive(name), 60):
                self.console.print(f"[red]{name} did not come up (see {c.out / 'stack.log'})[/red]")
                return False
        self._mark("services_alive")
        statuses: list[SafetyStatus] = []
        sub = s.declare_subscriber(self.keys.safety_status, lambda smp: statuses.append(decode(smp.payload.to_bytes())))
        if not wait_until(lambda: any(st.esdf_age_ms >= 0 for st in statuses[-5:]), 60):
            self.console.print("[red]no ESDF reached the safety filter[/red]")
            return False
        sub.undeclare()
        deadline = time.monotonic() + c.budget_s
        # -- teleoperation: the scripted operator visits the ball, then the dog --------------------
        self._mark("teleop_start")
        done = wait_until(lambda: (st := self._status(s, "operator", 1.0)) is not None
                          and st.extra.get("target_index", 0) >= len(TELEOP_TARGETS), max(5.0, 0.45 * c.budget_s))
        launcher.stop_one("operator")
        self._mark("teleop_end")
        # -- navigation: a loop round the table, then an unseen ball on the path -------------------
        wps = navigation_waypoints(c.laps)
        goal = NavGoal(waypoints=np.array([[x, y, 0.0] for x, y in wps]), tolerance=0.2, loop=False)
        s.put(self.keys.nav_goal, encode(goal), encoding=__import__("zenoh").Encoding(ENCODING))
        self._mark("navigation_start")
        spawned = False
        arrived = False
        while time.monotonic() < deadline:
            st = self._status(s, "navigator", 1.0)
            reached = int(st.extra.get("reached", 0)) if st else 0
            if not spawned and reached >= len(LOOP):
                s.put(self.keys.sim_spawn, json.dumps(UNSEEN).encode())
                spawned = True
                self._mark("unseen_obstacle_placed")
            if reached >= len(wps):
                arrived = True
                break
        self._mark("navigation_end" if arrived else "navigation_timeout")
        return bool(done) and arrived


# -- report -------------------------------------------------------------------------------------


def _scene_objects():
    """Ground truth: every object of the demo scene but floor and ceiling, plus the unseen ball."""

    full = build_scene(load_scenario(scenario()))
    objs = {o.name: o for o in full.objects if o.class_name not in ("floor", "ceiling")}
    objs[UNSEEN["name"]] = object_from_spec(ObjectSpec.model_validate(UNSEEN), UNSEEN["name"])
    return objs


def _clearances(cfg: DemoConfig, t: np.ndarray, xy: np.ndarray, placed_at: float) -> dict[str, np.ndarray]:
    """Clearance to every object along the trajectory, and ``"all"``: the minimum over them.
    The unseen ball counts only from the moment it was placed."""

    objs = _scene_objects()
    scenes = {name: Scene([o]) for name, o in objs.items()}
    clear = rp.clearance_series(lambda name, ts: scenes[name].at(ts), list(objs), t, xy, cfg.robot_radius,
                                t_sim0=float(t[0]))
    clear[UNSEEN["name"]] = np.where(t >= placed_at, clear[UNSEEN["name"]], np.inf)
    clear["all"] = np.min(np.vstack([clear[n] for n in objs]), axis=0)
    return clear


def make_report(cfg: DemoConfig, console: Console) -> dict:
    root = Keys(robot=cfg.robot).root
    st = rp.load_streams(cfg.out / "recording.mcap", root)
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
    inter = np.asarray([x.intervening and x.fallback is None for x in st.status], dtype=bool)
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
        tfi = rp.first_intervention(status_t, inter, window)
        per_class[TRACKED[obj]] = {
            "first_intervention_m": None if tfi is None else rp.interp(tfi, t, clear[obj]),
            "min_clearance_m": float(np.min(clear[obj][sel])),
        }
    # -- navigation ---------------------------------------------------------------------------------
    nav = (ph.get("navigation_start", 0.0), ph.get("navigation_end", ph.get("navigation_timeout", 0.0)))
    nsel = (t >= nav[0]) & (t <= nav[1])
    loop = np.asarray(LOOP + LOOP[:1])
    # deviation from the loop once the robot has joined it at the first waypoint
    joined = nsel & (np.cumsum(nsel & (np.linalg.norm(xy - loop[0], axis=1) < 0.3)) > 0)
    dev = _deviation(xy[joined], loop) if joined.any() else None
    unseen_min = float(np.min(clear["unseen_ball"][nsel & (t >= ph.get("unseen_obstacle_placed", np.inf))])) \
        if (nsel & (t >= ph.get("unseen_obstacle_placed", np.inf))).any() else None
    navigation = {"completed": "navigation_end" in ph, "max_deviation_m": dev,
                  "min_clearance_m": float(np.min(clear["all"][nsel])) if nsel.any() else None,
                  "unseen_obstacle_min_clearance_m": unseen_min}
    # -- system numbers ------------------------------------------------------------------------------
    collide = clear["all"] < 0
    rates = {k: v / max(st.duration_s, 1e-9) for k, v in sorted(st.counts.items())
             if not k.startswith(("status/", "invalid:"))}
    ages = [x.esdf_age_ms for x in st.status if x.esdf_age_ms >= 0]
    solve = [x.solve_us for x in st.status if x.fallback is None]
    latency = rp.command_latency_ms(st.ref_t, st.safe_t)
    fallbacks: dict[str, int] = {}
    for x in st.status:
        if x.fallback:
            fallbacks[x.fallback] = fallbacks.get(x.fallback, 0) + 1
    summary.update({
        "teleop": per_class, "navigation": navigation,
        "collisions": rp.episodes(collide), "min_clearance_m": float(np.min(clear["all"])),
        "min_clearance_per_object_m": {n: float(np.min(v)) for n, v in clear.items()
                                       if n != "all" and np.isfinite(np.min(v))},
        "rates_hz": rates, "esdf_age_ms": rp._stats(ages), "filter_step_us": rp._stats(solve),
        "command_latency_ms": rp._stats(latency), "fallbacks": fallbacks,
        "robot_radius_m": cfg.robot_radius,
    })
    _print(summary, console)
    try:
        _plots(cfg, st, t, clear, ph)
        summary["plots"] = ["teleop.png", "navigation.png"]
    except Exception as exc:  # a plot must never lose the numbers
        console.print(f"[yellow]plots skipped: {exc}[/yellow]")
    return summary


def _deviation(path: np.ndarray, loop: np.ndarray) -> float:
    """Largest distance from the driven path to the nominal loop polyline."""
    a, b = loop[:-1], loop[1:]
    ab = b - a
    best = np.full(len(path), np.inf)
    for i in range(len(a)):
        u = np.clip(((path - a[i]) @ ab[i]) / max(ab[i] @ ab[i], 1e-12), 0, 1)
        best = np.minimum(best, np.linalg.norm(path - (a[i] + u[:, None] * ab[i]), axis=1))
    return float(best.max())


def _print(summary: dict, console: Console) -> None:
    f = rp.fmt
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
    for key in ("camera/image", "perception/frame", "map/esdf", "state", "cmd/ref", "cmd/safe"):
        t3.add_row(f"rate {key}", f(summary["rates_hz"].get(key), " Hz", 1))
    for key, unit, label in (("esdf_age_ms", " ms", "ESDF age at the filter"),
                             ("filter_step_us", " µs", "filter step (field + QP)"),
                             ("command_latency_ms", " ms", "cmd/ref → cmd/safe latency")):
        s = summary[key]
        t3.add_row(f"{label} median / p99", "–" if s is None else f"{f(s['median'], unit)} / {f(s['p99'], unit)}")
    t3.add_row("braking reasons", ", ".join(f"{k}: {v}" for k, v in summary["fallbacks"].items()) or "none")
    out = Console()
    out.print(t1)
    out.print(t2)
    out.print(t3)


def _plots(cfg: DemoConfig, st: rp.Streams, t: np.ndarray, clear: dict, ph: dict) -> None:
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
