"""The ``mavlink`` node in its own process, talking to a pymavlink fake vehicle over UDP loopback."""

from __future__ import annotations

import math
import socket
import time
import uuid

import numpy as np
import pytest

from riskfield.edge.mavlink.fake_vehicle import FakeVehicle, VehicleModel
from riskfield.edge.mavlink.node import exposed_listener
from riskfield.protocol import Keys, RobotState, VelocityCommand
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


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cmd(vx: float, wz: float = 0.0) -> VelocityCommand:
    return VelocityCommand(linear=(vx, 0.0, 0.0), angular=(0.0, 0.0, wz), source="test")


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_mavlink_node_with_a_fake_vehicle(router_endpoint: str, autopilot: str, bad_velocity_payloads: list) -> None:
    robot = f"t_mav_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    port = free_udp_port()
    with client_session(router_endpoint) as s:
        states = Collector(s, keys.state, RobotState)
        status = StatusWatch(s, keys.status("mavlink"))
        args = ["--robot", robot, "--set", f"url=udpin:127.0.0.1:{port}", "--set", "status_period_s=0.05"]
        with ServiceProcess("mavlink", router_endpoint, args) as node, \
                FakeVehicle(f"udpout:127.0.0.1:{port}", autopilot, VehicleModel(x=5.0, yaw=0.0)) as veh:
            assert wait_alive(s, keys.alive("mavlink")), node.output
            # Streaming before any command: zero setpoints and a GCS heartbeat (their rates are the
            # bench's business, not this test's).
            assert wait_until(lambda: len(veh.setpoints()) >= 5 and len(veh.received.gcs_heartbeats) >= 1,
                              10.0), node.output
            assert all(m.vx == 0 and m.yaw_rate == 0 for _, m in veh.setpoints())
            assert any(c.command == 511 and int(c.param1) in (30, 32) for c in veh.received.commands)
            _, sp = veh.setpoints()[-1]
            assert (sp.target_system, sp.target_component, sp.coordinate_frame, sp.type_mask) == (1, 1, 8, 0x5C7)
            # Drive: forward and turning left (CCW) → body FRD vx > 0 and a negative (clockwise) yaw rate.
            # A teleop-like stream at ~20 Hz (the period is the scenario: a single command would
            # expire in the node's watchdog) until the vehicle has moved.
            assert wait_until(lambda: (put(s, keys.cmd_safe, cmd(0.5, 0.2)), veh.model.x > 5.2)[1], 10.0,
                              period_s=0.05), node.output
            _, sp = veh.setpoints()[-1]
            assert (sp.vx, sp.vy, sp.yaw_rate) == pytest.approx((0.5, 0.0, -0.2))
            assert veh.model.x > 5.2  # moved north
            # Watchdog: cmd/safe stops → zero setpoints keep streaming.
            t_last = time.perf_counter()
            # (its timing is checked with injected time in test_mavlink_core.py)
            assert wait_until(lambda: any(t > t_last and m.vx == 0 for t, m in veh.setpoints()), 5.0)
            # State: ENU, north → +y, heading turned clockwise in NED → ENU yaw = π/2 − yaw_NED.
            assert states.wait(10)
            st = states.items[-1]
            assert st.position[1] == pytest.approx(veh.model.x, abs=0.1)
            assert math.cos(st.yaw - (math.pi / 2 - veh.model.yaw)) == pytest.approx(1.0, abs=1e-3)
            assert all(np.isfinite(m.position).all() for m in states.items)
            # Bad input on both sides: Zenoh garbage and UDP garbage from the vehicle's address.
            n_bad = len(bad_velocity_payloads)
            assert put_each_rejected(s, keys.cmd_safe, bad_velocity_payloads, status, "cmd/safe") == n_bad
            veh.conn.port.sendto(bytes(range(256)) * 2, ("127.0.0.1", port))
            put(s, keys.cmd_safe, cmd(0.3))
            t1 = time.perf_counter()
            assert wait_until(lambda: any(t >= t1 and m.vx == pytest.approx(0.3) for t, m in veh.setpoints()), 3.0)
            assert node.alive()
            # Shutdown: the last word is a zero setpoint.
            t2 = time.perf_counter()
            put(s, keys.cmd_safe, cmd(0.3))
            assert wait_until(lambda: any(t >= t2 and m.vx == pytest.approx(0.3) for t, m in veh.setpoints()), 3.0)
            assert node.stop() == 0
            # Nothing is sent after the process ended: wait for the final datagram to be read.
            assert wait_until(lambda: veh.setpoints()[-1][1].vx == 0 and veh.setpoints()[-1][1].yaw_rate == 0, 2.0)
        states.close()
        status.close()


@pytest.mark.parametrize(("url", "published_on", "exposed"), [
    ("udpin:127.0.0.1:14550", None, None),  # the default: mavlink-router on this computer
    ("udpin:localhost:14550", None, None),
    ("udpin:0.0.0.0:14550", None, "0.0.0.0:14550"),
    ("udp:192.168.1.5:14550", None, "192.168.1.5:14550"),  # pymavlink's udp: listens too
    ("tcpin:[::]:5760", None, "[::]:5760"),
    ("udpin:0.0.0.0:14550", "127.0.0.1", None),  # a container published on the host's loopback
    ("udpin:0.0.0.0:14550", "0.0.0.0", "0.0.0.0:14550"),
    ("udpout:10.0.0.9:14550", None, None),  # dials out: accepts nothing unasked
    ("/dev/ttyACM0", None, None),
])
def test_a_listener_beyond_loopback_is_named(url: str, published_on: str | None, exposed: str | None) -> None:
    assert exposed_listener(url, published_on) == exposed
