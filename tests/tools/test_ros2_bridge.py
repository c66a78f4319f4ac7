"""ROS 2 CDR encodings, byte for byte, and the bridge node over a real router."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import RobotState, VelocityCommand
from riskfield.services.ros2_bridge.cdr import CdrReader
from riskfield.services.ros2_bridge.messages import (
    Odometry,
    decode_odometry,
    decode_twist,
    encode_odometry,
    encode_twist,
    odometry_to_state,
)
from riskfield.services.ros2_bridge.node import Ros2Bridge, ros_key
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive

f = st.floats(allow_nan=False, allow_infinity=False, width=64)


def test_twist_known_bytes():
    cmd = VelocityCommand(linear=(0.5, 0.0, 0.0), angular=(0.0, 0.0, -1.25), source="t")
    expected = bytes.fromhex("00010000") + struct.pack("<6d", 0.5, 0, 0, 0, 0, -1.25)
    assert encode_twist(cmd) == expected
    assert len(expected) == 52


def _odom() -> Odometry:
    return Odometry(sec=12, nanosec=345, frame_id="odom", child_frame_id="base_link",
                    position=(1.0, 2.0, 0.0), orientation=(0.0, 0.0, math.sin(0.25), math.cos(0.25)),
                    pose_covariance=tuple(float(i) for i in range(36)), linear=(0.4, 0.0, 0.0),
                    angular=(0.0, 0.0, 0.3), twist_covariance=tuple(0.5 * i for i in range(36)))


def test_odometry_known_bytes():
    o = _odom()
    body = struct.pack("<iI", 12, 345)
    body += struct.pack("<I", 5) + b"odom\x00"          # offset 8..17
    body += b"\x00" * 3 + struct.pack("<I", 10) + b"base_link\x00"  # align to 20, string ends at 34
    body += b"\x00" * 6                                   # align to 40 for float64
    body += struct.pack("<7d", 1, 2, 0, 0, 0, math.sin(0.25), math.cos(0.25))
    body += struct.pack("<36d", *range(36))
    body += struct.pack("<6d", 0.4, 0, 0, 0, 0, 0.3)
    body += struct.pack("<36d", *(0.5 * i for i in range(36)))
    assert encode_odometry(o) == b"\x00\x01\x00\x00" + body
    assert decode_odometry(encode_odometry(o)) == o


def test_odometry_matches_pycdr2():
    idl = pytest.importorskip("tools.ros_idl")
    Hdr, Odom, Pose, PoseCov, Quat, Time, Twist, TwistCov, Vec = (
        idl.Hdr, idl.Odom, idl.Pose, idl.PoseCov, idl.Quat, idl.Time, idl.Twist, idl.TwistCov, idl.Vec)
    o = _odom()
    ref = Odom(Hdr(Time(o.sec, o.nanosec), o.frame_id), o.child_frame_id,
               PoseCov(Pose(Vec(*o.position), Quat(*o.orientation)), list(o.pose_covariance)),
               TwistCov(Twist(Vec(*o.linear), Vec(*o.angular)), list(o.twist_covariance)))
    assert encode_odometry(o) == ref.serialize()
    cmd = VelocityCommand(linear=(0.1, 0.2, 0.3), angular=(0.4, 0.5, 0.6), source="t")
    assert encode_twist(cmd) == Twist(Vec(0.1, 0.2, 0.3), Vec(0.4, 0.5, 0.6)).serialize()


@settings(max_examples=100, deadline=None)
@given(st.tuples(f, f, f), st.tuples(f, f, f))
def test_twist_round_trip(lin, ang):
    assert decode_twist(encode_twist(VelocityCommand(linear=lin, angular=ang, source="x"))) == (lin, ang)


def test_odometry_to_state_rotates_body_twist_into_world():
    o = _odom()
    s = odometry_to_state(o)
    yaw = 0.5
    np.testing.assert_allclose(s.linear_velocity, [0.4 * math.cos(yaw), 0.4 * math.sin(yaw), 0], atol=1e-12)
    np.testing.assert_allclose(s.angular_velocity, [0, 0, 0.3], atol=1e-12)
    assert s.header.stamp_ns == 12 * 10**9 + 345 and s.yaw == pytest.approx(yaw)


@pytest.mark.parametrize("data", [b"", b"\x00\x00\x00\x00" + b"\x00" * 40, b"\x00\x01\x00\x00\x05"])
def test_malformed_cdr_is_rejected(data):
    with pytest.raises(ValueError):
        decode_odometry(data)
    with pytest.raises(ValueError):
        CdrReader(data).float64(6)


def test_watchdog_core():
    core = Ros2Bridge(watchdog_s=0.2)
    assert core.on_tick(0.0) is not None  # nothing yet: zeros
    core.on_cmd(VelocityCommand.zero("x"), 1.0)
    assert core.on_tick(1.1) is None and decode_twist(core.on_tick(1.3)) == ((0, 0, 0), (0, 0, 0))
    assert ros_key("/limo1/", "cmd_vel") == "limo1/cmd_vel" and ros_key("", "odom") == "odom"


def test_bridge_node_over_zenoh(router_endpoint):
    args = ["--robot", "t_ros", "--set", "namespace=t_ns"]
    with ServiceProcess("ros2-bridge", router_endpoint, args) as bridge, client_session(router_endpoint) as s:
        assert wait_alive(s, "rf/t_ros/alive/ros2-bridge"), bridge.output
        twists = Collector(s, "t_ns/cmd_vel")
        states = Collector(s, "rf/t_ros/state", RobotState)
        zeros = twists.wait(1)  # no cmd/safe yet: the watchdog streams zero Twists
        assert decode_twist(zeros[0]) == ((0, 0, 0), (0, 0, 0))
        cmd = VelocityCommand(linear=(0.3, 0, 0), angular=(0, 0, 0.2), source="safety-filter")
        twists.clear()
        for _ in range(3):
            put(s, "rf/t_ros/cmd/safe", cmd)
        assert any(t == encode_twist(cmd) for t in twists.wait(3))
        for junk in (b"", b"\x01\x02", b"\x00\x01\x00\x00" + b"\xff" * 7):
            s.put("t_ns/odom", junk)
        s.put("t_ns/odom", encode_odometry(_odom()))
        st_ = states.wait(1)[0]
        assert st_.position == (1.0, 2.0, 0.0)
        assert bridge.alive() and bridge.stop() == 0
        twists.close()
        states.close()
