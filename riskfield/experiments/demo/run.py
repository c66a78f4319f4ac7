"""Orchestration of ``riskfield demo``: start the stack, drive the two experiments, report.

The stack runs through the runtime's process runner; the experiments (the operator's approach
to the ball and the dog, the navigation loop with an unseen obstacle) are the ones the benches
run too (``riskfield.experiments.teleop`` and ``.navigation``), in the demo's room
(``riskfield.experiments.scenarios``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import yaml
from rich.console import Console
from rich.markup import escape

from riskfield.protocol import Keys, RobotState, SafetyStatus, decode
from riskfield.services.runtime.processes import Child, ProcessRunner, client_session, free_port, wait_until
from riskfield.services.runtime.warmup import KERNEL_SERVICES

from ..navigation import drive, place_unseen
from ..scenarios import CROSSER, LOOP, TELEOP_TARGETS, UNSEEN, navigation_waypoints, scenario
from ..stack import recording
from ..teleop import operator_args, wait_operator_done
from .config import DemoConfig
from .report import make_report


def camera_pipeline(c: DemoConfig, extra: dict[str, list[str]] | None = None) -> list[tuple[str, str, list[str]]]:
    """(label, service, arguments) of the services from the camera to ``cmd/safe``, as the demo runs
    them (``--robot`` aside), with ``extra`` arguments per label appended; ``riskfield bench latency``
    times the same ones. The scenario is ``c.out / "scenario.yaml"``."""
    rgbd = c.perception == "rgbd"  # the simulator's depth + odometry instead of degraded truth
    depth = ["--set", "publish_depth=true", "--set", "publish_truth=false"] if rgbd else []
    services = [
        ("simulator", "simulator", ["--set", f"scenario={c.out / 'scenario.yaml'}", *depth]),
        ("perception", "perception", ["--set", "geometry=rgbd"] if rgbd else []),
        ("mapping", "mapping", []),
        ("safety-filter", "safety-filter", ["--set", f"robot_radius={c.robot_radius}"]),
    ]
    return [(label, service, [*args, *(extra or {}).get(label, [])]) for label, service, args in services]


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

    def _runner(self) -> ProcessRunner:
        c, out = self.cfg, self.cfg.out
        common = ["--robot", c.robot]
        runner = ProcessRunner(self.endpoint, self.keys, log_path=out / "stack.log", echo=c.verbose,
                               console=self.console)
        runner.add("router", "router", common)
        runner.add("record", "record", [*common, "--set", f"out={out}"])
        for label, service, args in camera_pipeline(c):
            runner.add(label, service, [*common, *args])
        runner.add("navigator", "navigator", common)
        runner.add("operator", "operator", [*common, *operator_args(TELEOP_TARGETS, c.seed, c.teleop_push_s)])
        if c.live:
            runner.add("viewer", "viewer", [*common, "--set", "live=true", "--set", f"out={out}"])
        if c.foxglove:
            runner.add("foxglove", "foxglove", common)
        return runner

    def _how_to_watch(self) -> None:
        """Where the running demo can be watched from: its router is on a free port, not 7447."""
        c = self.cfg
        self.console.print(f"router {self.endpoint}: watch with `riskfield view --connect {self.endpoint} "
                           f"--robot {c.robot}` (add --foxglove for Foxglove)")
        if c.foxglove:
            from riskfield.services.recorder.live import layout

            path = c.out / "foxglove-layout.json"
            path.write_text(json.dumps(layout(self.keys.root), indent=2) + "\n")
            self.console.print(f"Foxglove: open ws://127.0.0.1:8765 and import the layout {path} (robot {c.robot})")

    def run(self) -> int:
        c = self.cfg
        c.out.mkdir(parents=True, exist_ok=True)
        (c.out / "scenario.yaml").write_text(yaml.safe_dump(scenario(), sort_keys=False))
        self.t0 = time.monotonic()
        runner = self._runner()
        ok = False
        if c.warm_up and not self._warm_up(runner):
            return 1
        try:
            runner.start()
            self._mark("stack_started")
            self._how_to_watch()
            with client_session(self.endpoint, timeout_s=30) as s:
                ok = self._experiments(s, runner)
        finally:
            runner.close()
            self._mark("stack_stopped")
        dead = runner.ended_badly()
        if dead:
            self.console.print(f"[red]services ended badly: {', '.join(dead)} (see {c.out / 'stack.log'})[/red]")
        (c.out / "phases.json").write_text(json.dumps(c.phases, indent=2) + "\n")
        summary = make_report(c, self.console)
        summary["services_ended_badly"] = dead
        summary["experiments_completed"] = ok
        (c.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        return 0 if ok and not dead and summary["collisions"] == 0 else 1

    def _warm_up(self, runner: ProcessRunner) -> bool:
        """``riskfield warmup`` for the demo's services with kernels, in a process of its own (as the
        nodes load them: this one stays light), its lines shown as they come."""
        services = sorted({child.service for child in runner.children.values()} & set(KERNEL_SERVICES))
        if not services:
            return True
        proc = subprocess.Popen([sys.executable, "-m", "riskfield", "warmup", *services], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        assert proc.stdout is not None
        for line in proc.stdout:
            self.console.print(f"[dim]{escape(line.rstrip())}[/dim]")
        if proc.wait() != 0:
            self.console.print(f"[red]riskfield warmup {' '.join(services)} failed (exit code {proc.returncode})[/red]")
            return False
        self._mark("kernels_ready")
        return True

    def _waiting(self, late: dict[str, Child], elapsed: float) -> None:
        """One line per service still starting, with what it last said (the kernel it compiles)."""
        for label, child in late.items():
            said = child.last_line.split(": ", 1)[-1] if child.last_line else "(nothing yet)"
            self.console.print(f"[dim]{elapsed:6.1f} s  waiting for {label}: {escape(said[:160])}[/dim]")

    def _experiments(self, s, runner: ProcessRunner) -> bool:
        c = self.cfg
        # As long as the services take to start, while each says what it does (every 5 s while it
        # starts, logs.StartupReport), up to ready_timeout_s: a cold numba cache on a busy machine
        # takes minutes, a node that went silent is stuck.
        if not runner.wait_ready(s, None, c.ready_timeout_s, quiet_s=c.quiet_s, progress=self._waiting,
                                 progress_every_s=10.0):
            late = [label for label in runner.children if label not in runner.ready(s)]
            self.console.print(f"[red]{', '.join(late)} did not come up (see {c.out / 'stack.log'})[/red]")
            return False
        self._mark("services_alive")
        statuses: list[SafetyStatus] = []
        sub = s.declare_subscriber(self.keys.safety_status, lambda smp: statuses.append(decode(smp.payload.to_bytes())))
        if not wait_until(lambda: any(st.esdf_age_ms >= 0 for st in statuses[-5:]), 60):
            refused = max((st.esdf_refused for st in statuses), default=0)
            if refused:  # they came, too old: the filter brakes on a stale map, as it must
                load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
                self.console.print(f"[red]the safety filter refused all {refused} ESDFs it got (fallback "
                                   f"{statuses[-1].fallback}): the camera → map path is slower than the map "
                                   f"timeout on this machine (load average {load:.1f}); see "
                                   f"{c.out / 'stack.log'}[/red]")
            else:
                self.console.print("[red]no ESDF reached the safety filter[/red]")
            return False
        sub.undeclare()
        deadline = time.monotonic() + c.budget_s
        # -- teleoperation: the scripted operator visits the ball, then the dog --------------------
        self._mark("teleop_start")
        done = wait_operator_done(s, self.keys, len(TELEOP_TARGETS), max(5.0, 0.45 * c.budget_s))
        runner.stop("operator")
        self._mark("teleop_end")
        # -- navigation: a loop round the table, then an unseen ball on the path -------------------
        wps = navigation_waypoints(c.laps)
        placed: list[bool] = []
        crossing: list[bool] = []

        def on_reached(n: int) -> None:
            if not crossing and n >= 1:  # on the first leg: a person crosses it (scenarios.CROSSER)
                place_unseen(s, self.keys, CROSSER)
                crossing.append(True)
                self._mark("walker_crossing")
            if not placed and n >= len(LOOP):
                place_unseen(s, self.keys, UNSEEN)
                placed.append(True)
                self._mark("unseen_obstacle_placed")

        with recording(s, {"state": (self.keys.state, RobotState)}) as rec:
            self._mark("navigation_start")
            result = drive(s, self.keys, rec, wps, 0.2, max(0.0, deadline - time.monotonic()), on_reached)
        self._mark("navigation_end" if result.completed else "navigation_timeout")
        return bool(done) and result.completed
