"""The navigator as a process over a real Zenoh router: closed loop, arrival, hostile input."""

from __future__ import annotations

import math
import signal
import time

import numpy as np
import pytest

from riskfield.protocol import NavGoal, NodeStatus, RobotState, VelocityCommand
from riskfield.testing import (
    Collector,
    ServiceProcess,
    StatusWatch,
    client_session,
    hostile_payloads,
    put,
    wait_alive,
    wait_until,
)


def state(x: float, y: float, yaw: float) -> RobotState:
    return RobotState(position=(x, y, 0.0), orientation=(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
                      linear_velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0))


@pytest.mark.slow
def test_closed_loop_over_zenoh_reaches_goal_and_stops(router_endpoint):
    robot = "t_nav_loop"
    args = ["--robot", robot, "--set", "rate_hz=50", "--set", "nav.v_max=0.8", "--set", "stop_hold_s=30"]
    with ServiceProcess("navigator", router_endpoint, args) as nav, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/navigator"), nav.output
        cmds = Collector(session, f"rf/{robot}/cmd/ref/navigator", VelocityCommand)
        goal = NavGoal(waypoints=np.array([[0.6, 0.0, 0.0], [0.6, 0.5, 0.0]]), tolerance=0.05, loop=False)
        x, y, yaw = 0.0, 0.0, 0.0
        put(session, f"rf/{robot}/state", state(x, y, yaw))
        put(session, f"rf/{robot}/nav/goal", goal)
        t_end, last = time.monotonic() + 15.0, time.monotonic()
        arrived = False
        while time.monotonic() < t_end:  # a unicycle integrated from the latest command
            time.sleep(0.02)  # the simulated robot's 50 Hz step (scenario); the loop ends on arrival
            now = time.monotonic()
            dt, last = now - last, now
            if cmds.items:
                c = cmds.items[-1]
                assert c.source == "navigator"
                x += dt * c.linear[0] * math.cos(yaw)
                y += dt * c.linear[0] * math.sin(yaw)
                yaw += dt * c.angular[2]
            put(session, f"rf/{robot}/state", state(x, y, yaw))
            if len(cmds.items) > 20 and all(
                    c.linear == (0, 0, 0) and c.angular == (0, 0, 0) for c in cmds.items[-5:]):
                arrived = True
                break
        assert arrived, nav.output
        assert math.hypot(x - 0.6, y - 0.5) < 0.05 + 0.05
        assert any(c.linear[0] > 0.1 for c in cmds.items)  # it did drive
        assert "final waypoint reached" in nav.output
        cmds.close()
        assert nav.stop(signal.SIGINT) == 0


def test_stale_state_gives_zero_commands(router_endpoint):
    robot = "t_nav_stale"
    args = ["--robot", robot, "--set", "rate_hz=50", "--set", "nav.state_timeout_s=0.2",
            "--set", "status_period_s=0.1"]
    with ServiceProcess("navigator", router_endpoint, args) as nav, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/navigator"), nav.output
        cmds = Collector(session, f"rf/{robot}/cmd/ref/navigator", VelocityCommand)
        status = StatusWatch(session, f"rf/{robot}/status/navigator")
        # Its loop has run for a while (uptime) without a goal: it published no command.
        assert status.wait(lambda st: st.uptime_s > 0.3).published.get("cmd/ref", 0) == 0
        assert cmds.items == []  # no goal yet: silent
        put(session, f"rf/{robot}/nav/goal",
              NavGoal(waypoints=np.array([[2.0, 0.0, 0.0]]), tolerance=0.05, loop=False))
        cmds.wait(5)
        assert all(c.linear == (0, 0, 0) for c in cmds.items)  # no state at all
        put(session, f"rf/{robot}/state", state(0, 0, 0))
        assert wait_until(lambda: any(c.linear[0] > 0 for c in cmds.items), 5)
        cmds.clear()
        # No more states: once the last one is older than state_timeout_s, commands are zero.
        assert wait_until(lambda: bool(cmds.items) and cmds.items[-1].linear == (0, 0, 0), 5)
        cmds.close()
        status.close()
        assert nav.stop() == 0


def test_hostile_goals_and_states_are_rejected_and_node_keeps_serving(router_endpoint):
    robot = "t_nav_fuzz"
    args = ["--robot", robot, "--set", "rate_hz=50", "--set", "status_period_s=0.2"]
    with ServiceProcess("navigator", router_endpoint, args) as nav, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/navigator"), nav.output
        cmds = Collector(session, f"rf/{robot}/cmd/ref/navigator", VelocityCommand)
        status = Collector(session, f"rf/{robot}/status/navigator", NodeStatus)
        goal = NavGoal(waypoints=np.array([[1.0, 1.0, 0.0]]), tolerance=0.05, loop=False)
        st = state(0, 0, 0)
        for payload in hostile_payloads(goal, 300, seed=7):
            put(session, f"rf/{robot}/nav/goal", payload)
        for payload in hostile_payloads(st, 300, seed=8):
            put(session, f"rf/{robot}/state", payload)
        assert wait_until(lambda: status.items and status.items[-1].invalid.get("nav/goal", 0) == 300
                          and status.items[-1].received.get("state", 0) == 300, 10), status.items[-1:]
        assert status.items[-1].published.get("cmd/ref", 0) == 0
        assert cmds.items == []  # nothing hostile became a goal
        put(session, f"rf/{robot}/state", st)
        put(session, f"rf/{robot}/nav/goal", goal)
        got = cmds.wait(3)
        assert got[-1].linear[0] >= 0 and abs(got[-1].angular[2]) > 0.1  # turning towards (1, 1)
        assert np.isfinite(got[-1].angular[2])
        assert wait_until(lambda: status.items and status.items[-1].invalid.get("nav/goal", 0) == 300
                          and status.items[-1].received.get("state", 0) == 301, 10)
        last = status.items[-1]
        # The latest-value queue drops superseded states before decoding; whatever was decoded
        # and hostile was rejected, and only the one valid state was used.
        assert last.invalid["state"] >= 1
        assert last.invalid["state"] + last.dropped["state"] == 300
        assert last.errors == 0
        assert nav.alive()
        cmds.close()
        status.close()
        assert nav.stop() == 0
