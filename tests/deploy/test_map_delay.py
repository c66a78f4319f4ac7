"""A map link that turns slow: the ESDF keeps arriving, but late. A robot's router and a server's on
loopback, joined by the user-space shaping relay (``shaped_link.py``; the kernels here have no
``netem``), the fault drills' agents (``deploy/faults/agents.py``: the ESDF source on the server, the
robot's inputs and the probe on the robot) and the real safety filter on the robot side.

The filter ages a map by its content stamp, not by its arrival: under a delay past the timeout it
must brake although maps keep coming, and drive again once they are timely.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from deploy import netns_lab as lab_mod
from riskfield.experiments.shaped_link import Shape, ShapedLink
from riskfield.testing import ServiceProcess, free_port, wait_until

pytestmark = pytest.mark.slow  # two routers, the filter and three agents, about half a minute

REPO = Path(__file__).resolve().parents[2]
AGENTS = REPO / "deploy" / "faults" / "agents.py"
ROBOT = "t_delay"
TIMEOUT_S = 0.3  # the filter's map_timeout_s default
SLACK_S = 0.15  # one filter period, the probe's hop and scheduling on a busy 2-core machine
CLOCK_TOLERANCE_S = 0.1  # the filter's clock_tolerance_s default: a map's content may be T + this old
DELAY_S = 0.8  # past TIMEOUT_S + CLOCK_TOLERANCE_S
RESUME_S = 8.0
LATE_MAPS = 10  # a second of late maps at the source's 10 Hz


class Agent:
    """One ``agents.py`` role in its own interpreter, its output in a file; stopped on exit."""

    def __init__(self, role: str, endpoint: str, log: Path, *args: str):
        self.log = log
        with open(log, "w") as f:
            self.proc = subprocess.Popen([sys.executable, str(AGENTS), role, "--connect", endpoint, "--robot", ROBOT,
                                          *args], stdout=f, stderr=subprocess.STDOUT)

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def site(tmp_path: Path) -> Iterator[tuple[Path, ShapedLink, list]]:
    """(the probe's file, the link, every process for the failure messages)."""
    server_ep, robot_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    common = ["--robot", ROBOT]
    probe = tmp_path / "probe.jsonl"
    agents: list[Agent] = []
    with ServiceProcess("router", server_ep, common) as server_router, \
            ShapedLink(int(server_ep.rsplit(":", 1)[1])) as link, \
            ServiceProcess("router", robot_ep, [*common, "--connect", link.endpoint]) as robot_router:
        try:
            agents.append(Agent("esdf-source", server_ep, tmp_path / "esdf.log"))
            agents.append(Agent("probe", robot_ep, tmp_path / "probe.log", "--out", str(probe)))
            agents.append(Agent("robot-inputs", robot_ep, tmp_path / "inputs.log"))
            with ServiceProcess("safety-filter", robot_ep, common) as filt:
                yield probe, link, [server_router, robot_router, filt, *agents]
        finally:
            for a in reversed(agents):
                a.stop()


def _outputs(procs: list) -> str:
    return "\n".join(f"--- {p.log.name}\n{p.log.read_text()[-2000:]}" if isinstance(p, Agent)
                     else f"--- {p.name}\n{p.output[-2000:]}" for p in procs)


def test_delay_past_the_timeout_brakes_while_late_maps_keep_arriving_and_resumes_after(site) -> None:
    probe, link, procs = site
    events = lambda: lab_mod.read_events(probe)  # noqa: E731
    driving = lambda t0: lab_mod.first_after(  # noqa: E731
        events(), t0, lambda e: e["k"] == "cmd" and not lab_mod.is_brake(e)) is not None
    assert wait_until(lambda: bool(lab_mod.esdf_times(events())) and driving(0.0), timeout_s=90), _outputs(procs)
    start = time.monotonic()
    link.shaped(Shape(delay_s=DELAY_S))
    late = lambda: [t for t in lab_mod.esdf_times(events()) if t > start + DELAY_S + SLACK_S]  # noqa: E731
    try:
        steady = wait_until(lambda: len(late()) >= LATE_MAPS, timeout_s=DELAY_S + RESUME_S)
    finally:
        link.shaped(Shape())
        end = time.monotonic()
    assert steady, f"late maps heard: {len(late())}\n{_outputs(procs)}"
    assert wait_until(lambda: driving(end), timeout_s=RESUME_S + 2), _outputs(procs)
    heard = events()
    brake = lab_mod.first_after(heard, start, lab_mod.is_brake)
    assert brake is not None, "no brake at all"
    latency = lab_mod.brake_delay_after_last_map(heard, start)
    moving = [e for e in heard if e["k"] == "cmd" and brake["t"] <= e["t"] <= end and not lab_mod.is_brake(e)]
    reasons = {e["fallback"] for e in heard if e["k"] == "status" and start + DELAY_S + SLACK_S < e["t"] < end}
    resumed = lab_mod.resume_delay(heard, end)
    print(f"\n[map delay] braked {latency} s after the last timely map, {len(late())} late maps, "
          f"{len(moving)} moving commands in the delay, driving {resumed} s after it ended")
    # The last timely map's content is older than its arrival: its content age passes T + ε no later.
    assert latency is not None and latency <= TIMEOUT_S + CLOCK_TOLERANCE_S + SLACK_S, f"braked {latency} s late"
    assert not moving, f"{len(moving)} moving command(s) on maps {DELAY_S} s old, first {moving[:1]}"
    assert reasons == {"stale_map"}, reasons
    assert resumed is not None and resumed <= RESUME_S
