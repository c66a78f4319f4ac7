"""A robot and a server in two network namespaces (deploy/faults/netns.sh), riskfield processes
inside them, and the analysis of what the robot side heard (deploy/faults/agents.py probe).

    with Lab("rft1") as lab:
        lab.start_server(source="esdf")          # router + a mapping stand-in (or the real mapping)
        lab.start_robot()                        # router dialling the server, safety filter, inputs, probe
        t = lab.cut(); ...; lab.heal()
        events = lab.events()

Everything the lab makes (namespaces, processes) is removed on exit, also after an error.
Timestamps are CLOCK_MONOTONIC, which every namespace of the machine shares.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
NETNS = REPO / "deploy" / "faults" / "netns.sh"
AGENTS = REPO / "deploy" / "faults" / "agents.py"
ROBOT_IP, SERVER_IP = "10.200.0.1", "10.200.0.2"
SERVER_EP = f"tcp/{SERVER_IP}:7447"
ROBOT_EP = "tcp/127.0.0.1:7447"  # the robot's router, inside the robot namespace


def netns_unavailable() -> str | None:
    """Why namespaces cannot be made here, or None."""
    if shutil.which("ip") is None or shutil.which("tc") is None:
        return "iproute2 (ip, tc) is not installed"
    if os.geteuid() != 0:
        return "network namespaces need root"
    proc = subprocess.run(["bash", str(NETNS), "probe"], capture_output=True, text=True, timeout=30,
                          env={**os.environ, "RF_NETNS": f"rfp{os.getpid() % 100000}"})
    return None if proc.returncode == 0 else (proc.stderr.strip() or "ip netns add failed")


@dataclass
class Proc:
    name: str
    popen: subprocess.Popen
    log: Path

    @property
    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def alive(self) -> bool:
        return self.popen.poll() is None

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> int:
        if self.popen.poll() is None:
            self.popen.send_signal(sig)
            try:
                self.popen.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait()
        return self.popen.returncode


@dataclass
class Lab:
    name: str
    robot: str = "netlab"
    tmp: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="rf-netlab-")))
    procs: dict[str, Proc] = field(default_factory=dict)

    # -- namespaces -------------------------------------------------------------------------------
    def sh(self, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        proc = subprocess.run(["bash", str(NETNS), *args], capture_output=True, text=True, timeout=30,
                              env={**os.environ, "RF_NETNS": self.name})
        if check and proc.returncode != 0:
            raise RuntimeError(f"netns.sh {' '.join(args)}: {proc.stderr.strip()}")
        return proc

    def __enter__(self) -> Lab:
        self.sh("down", check=False)  # leftovers of an interrupted run with the same name
        self.sh("up")
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            for p in reversed(list(self.procs.values())):
                p.stop()
        finally:
            self.sh("down", check=False)
            shutil.rmtree(self.tmp, ignore_errors=True)

    # -- processes ----------------------------------------------------------------------------------
    def spawn(self, side: str, name: str, argv: list[str]) -> Proc:
        """Run ``argv`` inside the ``side`` namespace (``netns.sh exec`` execs, so the pid is the program's)."""
        assert name not in self.procs or not self.procs[name].alive(), name
        log = self.tmp / f"{name}.log"
        env = {k: v for k, v in os.environ.items() if not k.startswith("RISKFIELD_")}
        env["PYTHONUNBUFFERED"] = "1"
        with open(log, "a") as f:
            popen = subprocess.Popen(["bash", str(NETNS), "exec", side, *argv], stdout=f, stderr=subprocess.STDOUT,
                                     env={**env, "RF_NETNS": self.name})
        self.procs[name] = Proc(name, popen, log)
        return self.procs[name]

    def riskfield(self, side: str, name: str, service: str, *args: str) -> Proc:
        return self.spawn(side, name, [sys.executable, "-m", "riskfield", "run", service, "--robot", self.robot,
                                       *args])

    def agent(self, side: str, name: str, role: str, connect: str, *args: str) -> Proc:
        return self.spawn(side, name, [sys.executable, str(AGENTS), role, "--connect", connect, "--robot", self.robot,
                                       *args])

    def start_server(self, source: str = "esdf") -> None:
        """The server site: its router and the ESDF source, ``esdf`` (a free-space stand-in for
        mapping) or ``mapping`` (the real mapping service fed with a wall pointmap)."""
        # In the clear on the lab's own veth link, which only the two namespaces reach.
        self.riskfield("server", "server-router", "router", "--listen", SERVER_EP, "--set", "insecure=true")
        self.start_source(source)

    def start_source(self, source: str) -> None:
        if source == "esdf":
            self.agent("server", "mapping", "esdf-source", SERVER_EP)
        else:
            self.agent("server", "perception", "frame-source", SERVER_EP)
            self.riskfield("server", "mapping", "mapping", "--connect", SERVER_EP)

    def start_robot(self) -> None:
        """The robot site: its router (dialling the server's), the safety filter, the robot's
        inputs and the probe."""
        self.riskfield("robot", "robot-router", "router", "--listen", ROBOT_EP, "--connect", SERVER_EP)
        self.agent("robot", "probe", "probe", ROBOT_EP, "--out", str(self.probe_file))
        self.agent("robot", "inputs", "robot-inputs", ROBOT_EP)
        self.riskfield("robot", "safety-filter", "safety-filter", "--connect", ROBOT_EP)

    # -- faults --------------------------------------------------------------------------------------
    def cut(self) -> float:
        self.sh("cut")
        return time.monotonic()

    def heal(self) -> float:
        self.sh("heal")
        return time.monotonic()

    def loss(self, pct: float) -> float:
        self.sh("loss", str(pct))
        return time.monotonic()

    def clear(self) -> float:
        self.sh("clear")
        return time.monotonic()

    def kill(self, name: str) -> float:
        """SIGKILL: a crash, no goodbye on the network."""
        self.procs[name].stop(signal.SIGKILL)
        return time.monotonic()

    # -- what the robot heard -------------------------------------------------------------------------
    @property
    def probe_file(self) -> Path:
        return self.tmp / "probe.jsonl"

    def events(self) -> list[dict]:
        return read_events(self.probe_file)

    def outputs(self) -> str:
        return "\n".join(f"--- {n} (alive={p.alive()})\n{p.output[-3000:]}" for n, p in self.procs.items())


# -- analysis (pure) ---------------------------------------------------------------------------------


def read_events(probe_file: Path) -> list[dict]:
    """The probe's events so far (``deploy/faults/agents.py probe``), in the order heard."""
    if not probe_file.exists():
        return []
    out = []
    for line in probe_file.read_text().splitlines():
        with contextlib.suppress(json.JSONDecodeError):  # a line being written
            out.append(json.loads(line))
    return out


def is_brake(event: dict) -> bool:
    return event["k"] == "cmd" and not any(event["linear"]) and not any(event["angular"])


def esdf_times(events: list[dict]) -> list[float]:
    return [e["t"] for e in events if e["k"] == "esdf"]


def first_after(events: list[dict], t: float, pred) -> dict | None:
    return next((e for e in events if e["t"] > t and pred(e)), None)


def last_before(times: list[float], t: float) -> float | None:
    prior = [x for x in times if x <= t]
    return prior[-1] if prior else None


@dataclass(frozen=True)
class Violation:
    t: float
    map_age_s: float
    command: dict


def stale_commands_not_braking(events: list[dict], t0: float, t1: float, limit_s: float,
                               heard_slack_s: float) -> tuple[int, list[Violation]]:
    """The fail-safe invariant for the commands heard on [t0, t1]: every command made from map
    content older than ``limit_s`` (the filter's timeout plus its clock tolerance) is a brake.
    Returns (commands checked, violations).

    Judged on stamps, not on when the probe heard things: a command's stamp is the wall clock its
    filter step judged freshness by, an ESDF's the time of its content, so no scheduling delay of
    the probe's enters the age. (By arrival times, CI once failed on a command heard 0.50 s after
    the probe's last map: under loss an ESDF and a command made from it reach the probe in either
    order.) The content the step can have had is the newest ESDF stamped no later than the step
    that the probe heard no later than ``heard_slack_s`` after the command: a map the link held back
    and delivered long after the step cannot have been used by it."""
    maps = [(e["t"], e["stamp_ns"]) for e in events if e["k"] == "esdf"]
    checked, bad = 0, []
    for e in events:
        if e["k"] != "cmd" or not t0 <= e["t"] <= t1:
            continue
        usable = [stamp for heard, stamp in maps if stamp <= e["stamp_ns"] and heard <= e["t"] + heard_slack_s]
        age = (e["stamp_ns"] - max(usable)) * 1e-9 if usable else float("inf")
        if age > limit_s:
            checked += 1
            if not is_brake(e):
                bad.append(Violation(e["t"], age, e))
    return checked, bad


def brake_delay_after_last_map(events: list[dict], fault_t: float) -> float | None:
    """Seconds from the last ESDF heard to the first brake after the fault (maps still in flight
    when the fault began count: the staleness timeout runs from the last one heard)."""
    brake = first_after(events, fault_t, is_brake)
    if brake is None:
        return None
    last = last_before(esdf_times(events), brake["t"])
    return None if last is None else brake["t"] - last


def resume_delay(events: list[dict], restore_t: float) -> float | None:
    """Seconds from the fault's end to the first command that is not a brake."""
    moving = first_after(events, restore_t, lambda e: e["k"] == "cmd" and not is_brake(e))
    return None if moving is None else moving["t"] - restore_t
