"""The ``limo`` node in its own process over a real router, against the pty chassis emulator."""

from __future__ import annotations

import math
import os
import signal
import threading
import time
import uuid
from pathlib import Path

import pytest

from riskfield.edge.limo import protocol as p
from riskfield.edge.limo.emulator import ChassisEmulator
from riskfield.edge.limo.messages import LimoDiagnostics, decode_diagnostics
from riskfield.protocol import EsdfGrid, Keys, RobotState, SafetyStatus, VelocityCommand
from riskfield.services.fields import AnalyticField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Sphere
from riskfield.testing import (
    Collector,
    ServiceProcess,
    StatusWatch,
    client_session,
    put,
    put_each_rejected,
    wait_alive,
    wait_until,
)


def free_space_map() -> EsdfGrid:
    """An ESDF around the LIMO's odometry origin with one far obstacle: the filter lets it drive."""
    far = AnalyticField(Sphere([5.5, 2.5, 0.0], 0.3, planar=True, label=2), groups=["high", "mid", "low"])
    return to_grid_message(to_esdf(far, [-3, -3, 0], [6, 3, 0], 0.1, planar=True))


def cmd(vx: float, wz: float = 0.0) -> VelocityCommand:
    return VelocityCommand(linear=(vx, 0.0, 0.0), angular=(0.0, 0.0, wz), source="test")


def motions(emu: ChassisEmulator, since: float = 0.0) -> list[p.MotionCommand]:
    return [m for t, m in emu.frames(p.MotionCommand) if t >= since]


def diag(col: Collector) -> LimoDiagnostics:
    return decode_diagnostics(col.items[-1])


def start(robot: str, endpoint: str, port: str, *extra: str) -> ServiceProcess:
    return ServiceProcess("limo", endpoint, ["--robot", robot, "--set", f"port={port}",
                                             "--set", "reconnect_s=0.1", "--set", "status_period_s=0.05", *extra])


def test_limo_node_drives_publishes_state_and_stops(router_endpoint: str, tmp_path: Path) -> None:
    robot = f"t_limo_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    with ChassisEmulator(link=str(tmp_path / "limo")) as emu, client_session(router_endpoint) as s:
        states = Collector(s, keys.state, RobotState)
        diags = Collector(s, keys.key("limo/diagnostics"))
        with start(robot, router_endpoint, emu.port) as node:
            assert wait_alive(s, keys.alive("limo")), node.output
            assert wait_until(lambda: emu.model.control_mode == 1, 5.0), node.output
            # Drive: a teleop-like stream at ~25 Hz (the period is the scenario: one command alone
            # would expire in the watchdog) until the chassis moved and turned, then one command
            # beyond the platform limit.
            assert wait_until(lambda: (put(s, keys.cmd_safe, cmd(0.4, 0.3)), emu.model.x > 0.1 and
                                       any(m == p.MotionCommand(0.4, 0.3) for m in motions(emu)))[1],
                              10.0, period_s=0.04), node.output
            put(s, keys.cmd_safe, cmd(5.0))
            assert wait_until(lambda: any(m.linear == 1.0 for m in motions(emu)), 2.0)
            assert all(abs(m.linear) <= 1.0 for m in motions(emu))
            # Watchdog: no more commands → a stop frame (its timing is checked with injected time in
            # test_limo_bridge.py; here only that the process does it).
            t_last = time.perf_counter()
            assert wait_until(lambda: any(m.is_stop for m in motions(emu, t_last)), 5.0)
            assert emu.model.v == 0.0
            # State: the estimate moved forward and turned left, all values finite.
            states.wait(5)
            st = states.items[-1]
            assert st.position[0] > 0.1 and st.yaw > 0.05
            assert st.position == tuple(float(v) for v in st.position)
            assert all(math.isfinite(v) for m in states.items for v in (*m.position, *m.linear_velocity))
            assert abs(st.position[0] - emu.model.x) < 0.05
            assert wait_until(lambda: diags.items and diag(diags).watchdog_stops >= 1, 2.0)
            d = diag(diags)
            assert d.connected and d.command_mode_confirmed and d.frames_ok > 10 and d.frames_bad == 0
            assert d.battery_v > 11
            # Shutdown: a clean exit leaves a stop frame as the last word.
            put(s, keys.cmd_safe, cmd(0.3))
            assert wait_until(lambda: emu.model.v == 0.3, 2.0)
            t0 = time.perf_counter()
            assert node.stop(signal.SIGTERM) == 0
            assert any(m.is_stop for m in motions(emu, t0)), node.output
        states.close()
        diags.close()


def test_limo_node_without_publish_state_drives_but_leaves_state_to_another_source(router_endpoint: str,
                                                                                   tmp_path: Path) -> None:
    """publish_state=false (a simulator is the robot's one `state`, deploy/compose.limo-emulator.yml):
    the chassis still obeys `cmd/safe` and reports diagnostics, and no `state` comes from it."""
    robot = f"t_limo_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    with ChassisEmulator(link=str(tmp_path / "limo")) as emu, client_session(router_endpoint) as s:
        states = Collector(s, keys.state, RobotState)
        diags = Collector(s, keys.key("limo/diagnostics"))
        with start(robot, router_endpoint, emu.port, "--set", "publish_state=false") as node:
            assert wait_alive(s, keys.alive("limo")), node.output
            assert wait_until(lambda: (put(s, keys.cmd_safe, cmd(0.4)), emu.model.x > 0.1)[1], 10.0,
                              period_s=0.04), node.output
            assert wait_until(lambda: diags.items and diag(diags).frames_ok > 10, 5.0)
            assert states.items == []
        states.close()
        diags.close()


def test_limo_node_survives_bad_input_and_a_vanishing_port(router_endpoint: str, tmp_path: Path,
                                                           bad_velocity_payloads: list[bytes]) -> None:
    robot = f"t_limo_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    with ChassisEmulator(link=str(tmp_path / "limo")) as emu, client_session(router_endpoint) as s:
        diags = Collector(s, keys.key("limo/diagnostics"))
        states = Collector(s, keys.state)
        status = StatusWatch(s, keys.status("limo"))
        with start(robot, router_endpoint, emu.port) as node:
            assert wait_alive(s, keys.alive("limo")), node.output
            assert wait_until(lambda: emu.model.control_mode == 1, 5.0)
            n_bad = len(bad_velocity_payloads)
            assert put_each_rejected(s, keys.cmd_safe, bad_velocity_payloads, status, "cmd/safe") == n_bad
            t0 = time.perf_counter()
            put(s, keys.cmd_safe, cmd(0.25))
            assert wait_until(lambda: any(m.linear == 0.25 for m in motions(emu, t0)), 3.0), node.output
            assert not any(m.linear not in (0.0, 0.25) for m in motions(emu, t0))
            # The port disappears: the node keeps serving and says so.
            emu.disconnect()
            assert wait_until(lambda: diags.items and not diag(diags).connected, 3.0), node.output
            n_states = len(states.items)
            last = status.wait(lambda st: True)
            received = status.wait(lambda st: st.uptime_s > last.uptime_s).received.get("cmd/safe", 0)  # a fresh one
            put(s, keys.cmd_safe, cmd(0.3))  # nowhere to go: must not crash the node
            status.wait(lambda st: st.received.get("cmd/safe", 0) > received)
            assert node.alive()
            assert len(states.items) <= n_states + 1  # no state without feedback
            assert "LIMO serial link lost" in node.output
            # A new device appears at the path: reconnect, command mode again, commands flow.
            emu.model.control_mode = 0
            emu.reconnect()
            assert wait_until(lambda: emu.model.control_mode == 1, 5.0), node.output
            t1 = time.perf_counter()
            put(s, keys.cmd_safe, cmd(0.35))
            assert wait_until(lambda: any(m.linear == 0.35 for m in motions(emu, t1)), 3.0)
            assert wait_until(lambda: diag(diags).connected and diag(diags).reconnects >= 1, 3.0)
            assert states.wait(len(states.items) + 2, 3.0)
            assert node.stop() == 0
        for c in (diags, states, status):
            c.close()


@pytest.mark.parametrize("timed", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_after_the_filter_is_sigkilled_the_watchdog_stops_the_chassis(router_endpoint: str, tmp_path: Path,
                                                                      timed: bool) -> None:
    """The real chain ref → safety filter → cmd/safe → LIMO node → chassis; the filter dies by
    SIGKILL (no brake of its own can go out): the bridge's watchdog stops the platform. ``timed``
    (slow): within its period (plus one poll and a scheduling margin) of the last command, a
    wall-clock bound a loaded machine can miss."""
    robot = f"t_limo_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    watchdog_s, poll_s = 0.2, 0.005
    grid = free_space_map()
    stop_feed = threading.Event()
    with ChassisEmulator(link=str(tmp_path / "limo")) as emu, client_session(router_endpoint) as s, \
            start(robot, router_endpoint, emu.port, "--set", f"watchdog_s={watchdog_s}",
                  "--set", f"poll_s={poll_s}") as node, \
            ServiceProcess("safety-filter", router_endpoint, ["--robot", robot]) as sf:
        assert wait_alive(s, keys.alive("limo")) and wait_alive(s, keys.alive("safety-filter")), sf.output
        status = Collector(s, keys.safety_status, SafetyStatus)

        def feed() -> None:  # a teleop reference and a live mapper (fresh stamps), at 20 Hz (scenario)
            while not stop_feed.is_set():
                grid.header.stamp_ns = time.time_ns()
                put(s, keys.esdf, grid)
                put(s, keys.cmd_ref, cmd(0.3))
                stop_feed.wait(0.05)

        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        try:
            assert wait_until(lambda: emu.model.v > 0.1, 20.0), (status.items[-1:], sf.output, node.output)
            assert status.items[-1].fallback is None
            t_kill = time.perf_counter()
            os.kill(sf.proc.pid, signal.SIGKILL)  # the reference keeps asking to move
            assert wait_until(lambda: emu.model.v == 0.0, 5.0), node.output
            moving = [t for t, m in emu.frames(p.MotionCommand) if not m.is_stop]
            stops = [t for t, m in emu.frames(p.MotionCommand) if m.is_stop and t > moving[-1]]
            assert stops, node.output  # the chassis stopped on a stop frame after the last command
            latency = stops[0] - moving[-1]
            if timed:
                assert moving[-1] < t_kill + 0.1  # the last moving frame came from the live filter
                assert latency <= watchdog_s + 0.15, latency  # the watchdog period + a busy machine's margin
            print(f"\nwatchdog stop {1e3 * latency:.0f} ms after the last command "
                  f"({1e3 * (stops[0] - t_kill):.0f} ms after SIGKILL)")
        finally:
            stop_feed.set()
            feeder.join(2)
            status.close()
        assert sf.proc.wait(5) == -signal.SIGKILL


def test_dry_run_sends_only_stop_frames_on_the_real_port_and_counts_what_it_withheld(router_endpoint: str,
                                                                                     tmp_path: Path) -> None:
    """``dry_run=true`` (first bring-up): the port opens and command mode is enabled as usual, the
    chassis's feedback comes back, but every motion frame on the line is zero while cmd/safe asks
    to move, and the status counts each withheld command."""
    robot = f"t_limo_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    with ChassisEmulator(link=str(tmp_path / "limo")) as emu, client_session(router_endpoint) as s:
        diags = Collector(s, keys.key("limo/diagnostics"))
        status = StatusWatch(s, keys.status("limo"))
        with start(robot, router_endpoint, emu.port, "--set", "dry_run=true") as node:
            assert wait_alive(s, keys.alive("limo")), node.output
            assert wait_until(lambda: emu.model.control_mode == 1, 5.0), node.output
            sent = 0

            def ask() -> bool:
                nonlocal sent
                put(s, keys.cmd_safe, cmd(0.4, 0.3))
                sent += 1
                st = status.latest
                return st is not None and st.extra.get("withheld_commands", 0) >= 5

            assert wait_until(ask, 10.0, period_s=0.04), node.output
            st = status.wait(lambda st: st.extra.get("withheld_commands", 0) >= 5)
            assert st.extra["dry_run"] == 1.0
            assert 5 <= st.extra["withheld_commands"] <= sent
            assert st.extra["withheld_commands"] == st.extra["commands"]  # every one of them was nonzero
            frames = motions(emu)
            assert frames and all(m.is_stop for m in frames), frames
            assert emu.model.v == 0.0 and emu.model.x == 0.0
            assert wait_until(lambda: diags.items and diag(diags).frames_ok > 10, 5.0)  # the feedback is real
            assert "dry run: withheld cmd/safe linear=0.400" in node.output
            assert node.stop() == 0
        diags.close()
        status.close()
