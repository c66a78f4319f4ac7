"""The ``mavlink`` node listens to the configured vehicle only: real UDP on 127.0.0.1, pymavlink on
both sides. Another system (a second vehicle, a forged sender) and another component of the same
system (a camera) put position streams on the same port; they never reach ``state`` and are
counted."""

from __future__ import annotations

import socket
import uuid

import pytest
from pymavlink import mavutil

from riskfield.edge.mavlink.bridge import MavlinkBridge, MavlinkConfig
from riskfield.edge.mavlink.fake_vehicle import FakeVehicle, VehicleModel
from riskfield.protocol import Keys, RobotState
from riskfield.testing import Collector, ServiceProcess, StatusWatch, client_session, wait_alive, wait_until

MAV = mavutil.mavlink


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_core_accepts_only_the_configured_vehicle() -> None:
    core = MavlinkBridge(MavlinkConfig())
    assert (core.config.vehicle_system, core.config.vehicle_component) == (1, 1)  # PX4's and ArduPilot's defaults
    assert core.accepts(1, 1) and not core.accepts(2, 1) and not core.accepts(1, 100)
    assert core.counters.foreign_messages == 2
    other = MavlinkBridge(MavlinkConfig(vehicle_system=3, vehicle_component=1))
    assert other.accepts(3, 1) and not other.accepts(1, 1)
    with pytest.raises(ValueError, match="vehicle_system"):
        MavlinkConfig(vehicle_system=0)


def test_udp_from_another_system_or_component_never_reaches_state(router_endpoint: str) -> None:
    keys = Keys(f"t_mav_foreign_{uuid.uuid4().hex[:6]}")
    port = free_udp_port()
    with client_session(router_endpoint) as s:
        states = Collector(s, keys.state, RobotState)
        status = StatusWatch(s, keys.status("mavlink"))
        args = ["--robot", keys.robot, "--set", f"url=udpin:127.0.0.1:{port}", "--set", "status_period_s=0.05"]
        with ServiceProcess("mavlink", router_endpoint, args) as node, \
                FakeVehicle(f"udpout:127.0.0.1:{port}", "px4", VehicleModel(x=5.0)):
            assert wait_alive(s, keys.alive("mavlink")), node.output
            assert states.wait(3), node.output  # the vehicle's own state: 5 m north → ENU y = 5
            impostors = [mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=sysid,
                                                    source_component=compid)
                         for sysid, compid in ((7, 1), (1, MAV.MAV_COMP_ID_CAMERA))]
            try:
                def flood() -> bool:
                    for conn in impostors:
                        conn.mav.heartbeat_send(MAV.MAV_TYPE_GROUND_ROVER, MAV.MAV_AUTOPILOT_PX4, 0, 0, 0)
                        conn.mav.local_position_ned_send(0, 500.0, -300.0, 0.0, 0.0, 0.0, 0.0)
                        conn.mav.attitude_send(0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
                    st = status.latest
                    return st is not None and st.extra.get("foreign_messages", 0) >= 60

                assert wait_until(flood, 15.0, period_s=0.02), (status.latest, node.output)
                n = len(states.items)
                assert states.wait(n + 3)  # states published after the flood was counted
            finally:
                for conn in impostors:
                    conn.close()
            assert all(abs(st.position[1] - 5.0) < 0.5 and abs(st.position[0]) < 0.5 for st in states.items), [
                st.position for st in states.items if abs(st.position[1] - 5.0) >= 0.5]
            assert "the vehicle is system 1 component 1" in node.output
            assert node.stop() == 0, node.output
        states.close()
        status.close()
