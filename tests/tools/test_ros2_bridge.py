"""ROS 2 bridge: every message type cross-checked between rosbags (what the bridge uses) and
pycdr2 classes written from the official .msg files (``tools.ros_idl``), the costmap values,
frames, twist_mux arbitration, and the node over a real router (garbage on every key)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from tools import ros_idl as idl  # pycdr2: the dev extra's, a broken install fails here rather than skipping

from riskfield.protocol import EsdfGrid, Header, NodeStatus, RobotState, SafetyStatus, VelocityCommand
from riskfield.services.ros2_bridge.messages import (
    CdrError,
    FrameMismatch,
    Odometry,
    RosCodec,
    Transform,
    costmap,
    nav2_cost,
    odometry_to_state,
    state_to_tf,
)
from riskfield.services.ros2_bridge.node import Ros2Bridge, Ros2BridgeSettings, ros_key
from riskfield.services.runtime.arbiter import CommandMux, MuxInput
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_until

f = st.floats(allow_nan=False, allow_infinity=False, width=64)
vec = st.tuples(f, f, f)
name = st.text(st.characters(codec="ascii", exclude_characters="\x00"), max_size=20)
stamp = st.integers(0, 2**31 * 10**9 - 1)


@pytest.fixture(scope="module", params=["humble", "jazzy"])
def codec(request) -> RosCodec:
    return RosCodec(request.param)


def _time(ns: int):
    return idl.Time(ns // 10**9, ns % 10**9)


def _cmd(lin, ang) -> VelocityCommand:
    return VelocityCommand(linear=lin, angular=ang, source="t")


# -- cross-checks: rosbags ⇄ pycdr2, both ways, byte for byte --------------------------------------
@settings(max_examples=60, deadline=None)
@given(vec, vec, stamp, name)
def test_twist_and_twist_stamped_match_pycdr2(lin, ang, ns, frame):
    codec = RosCodec("jazzy")
    ref = idl.Twist(idl.Vec(*lin), idl.Vec(*ang))
    ours = codec.encode_twist(_cmd(lin, ang), "Twist")
    assert ours == ref.serialize() and idl.Twist.deserialize(ours) == ref
    assert codec.decode_twist(ref.serialize(), "Twist") == (lin, ang, "")
    ref_s = idl.TwistStamped(idl.Hdr(_time(ns), frame), ref)
    ours_s = codec.encode_twist(_cmd(lin, ang), "TwistStamped", ns, frame)
    assert ours_s == ref_s.serialize() and idl.TwistStamped.deserialize(ours_s) == ref_s
    assert codec.decode_twist(ref_s.serialize(), "TwistStamped") == (lin, ang, frame)


@settings(max_examples=40, deadline=None)
@given(vec, st.tuples(f, f, f, f), vec, vec, stamp, name, name)
def test_odometry_matches_pycdr2(pos, quat, lin, ang, ns, frame, child):
    codec = RosCodec("humble")
    o = Odometry(ns, frame, child, pos, quat, lin, ang)
    cov = [0.0] * 36
    ref = idl.Odom(idl.Hdr(_time(ns), frame), child,
                   idl.PoseCov(idl.Pose(idl.Vec(*pos), idl.Quat(*quat)), cov),
                   idl.TwistCov(idl.Twist(idl.Vec(*lin), idl.Vec(*ang)), cov))
    assert codec.encode_odometry(o) == ref.serialize()
    assert idl.Odom.deserialize(codec.encode_odometry(o)) == ref
    assert codec.decode_odometry(ref.serialize()) == o


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(name, name, vec, st.tuples(f, f, f, f), stamp), max_size=4))
def test_tf_message_matches_pycdr2(items):
    codec = RosCodec("jazzy")
    trs = [Transform(p, c, t, q, ns) for p, c, t, q, ns in items]
    ref = idl.TFMessage([idl.TransformStamped(idl.Hdr(_time(ns), p), c, idl.Transform(idl.Vec(*t), idl.Quat(*q)))
                         for p, c, t, q, ns in items])
    assert codec.encode_tf(trs) == ref.serialize()
    assert idl.TFMessage.deserialize(codec.encode_tf(trs)) == ref
    assert codec.decode_tf(ref.serialize()) == trs


def wall_grid(frame: str = "map") -> EsdfGrid:
    """A 2-D slice with a wall at x = 1 (distance 1 − x), groups by row, odd sizes on purpose."""
    nx, ny, v = 31, 11, 0.05
    x = -0.2 + v * np.arange(nx)
    d = np.repeat((1.0 - x)[:, None], ny, axis=1)[:, :, None].astype(np.float32)
    rg = np.zeros((nx, ny, 1), np.uint8)
    rg[:, :4], rg[:, 4:8], rg[:, 8:] = 1, 2, 3
    return EsdfGrid(header=Header(stamp_ns=123_456_789_012, frame_id=frame), origin=(-0.2, 0.3, 0.0),
                    voxel_size=v, distance=d, risk_group=rg, groups=["high", "mid", "low"], max_distance=2.0,
                    unknown_is_occupied=False)


def test_occupancy_grid_matches_pycdr2_and_rosbags(codec):
    esdf = wall_grid()
    data = costmap(esdf, {"high": 3.0}, 10.0, 0.1, 0.55)
    raw = codec.encode_occupancy_grid(esdf, data, esdf.header.stamp_ns)
    ref = idl.OccupancyGrid.deserialize(raw)
    assert (ref.info.width, ref.info.height) == (31, 11) and ref.header.frame_id == "map"
    assert ref.info.resolution == pytest.approx(0.05)
    assert (ref.info.origin.position.x, ref.info.origin.position.y) == pytest.approx((-0.225, 0.275))
    cells = np.asarray(ref.data, np.int8).reshape(11, 31)  # row-major, x fastest
    np.testing.assert_array_equal(cells.T, data)
    assert ref.serialize() == raw
    back = codec.ts.deserialize_cdr(ref.serialize(), "nav_msgs/msg/OccupancyGrid")
    np.testing.assert_array_equal(back.data.reshape(11, 31).T, data)


def test_diagnostics_match_pycdr2(codec):
    status = SafetyStatus(h=0.12, risk_group=1, intervening=True, fallback=None, solve_us=40.0, esdf_age_ms=12.0)
    raw = codec.encode_diagnostics(status, "rf/limo1", 5 * 10**9 + 7)
    ref = idl.DiagnosticArray.deserialize(raw)
    s = ref.status[0]
    assert (s.level, s.hardware_id, ref.header.stamp) == (1, "rf/limo1", idl.Time(5, 7))
    assert {kv.key: kv.value for kv in s.values}["h"] == "0.1200"
    assert ref.serialize() == raw
    back = codec.ts.deserialize_cdr(ref.serialize(), "diagnostic_msgs/msg/DiagnosticArray")
    assert back.status[0].message == s.message == "intervening"
    braking = codec.ts.deserialize_cdr(codec.encode_diagnostics(
        SafetyStatus(h=0, risk_group=0, intervening=True, fallback="stale_map", solve_us=0, esdf_age_ms=-1),
        "x", 0), "diagnostic_msgs/msg/DiagnosticArray")
    assert braking.status[0].level == 2 and "stale_map" in braking.status[0].message


@pytest.mark.parametrize("raw", [b"", b"\x00\x01\x00\x00", b"\x00\x01\x00\x00" + b"\x00" * 60, b"\x07\x07" + bytes(50),
                                 b"\x00\x01\x00\x00" + b"\xff" * 7])
def test_malformed_cdr_is_rejected(codec, raw):
    for decode in (lambda r: codec.decode_twist(r, "Twist"), lambda r: codec.decode_twist(r, "TwistStamped"),
                   codec.decode_odometry, codec.decode_tf):
        with pytest.raises(CdrError):
            decode(raw)


def test_non_finite_values_are_rejected(codec):
    with pytest.raises(CdrError, match="finite"):
        codec.decode_twist(idl.Twist(idl.Vec(math.nan, 0, 0), idl.Vec(0, 0, 0)).serialize())
    with pytest.raises(CdrError, match="finite"):
        codec.decode_tf(idl.TFMessage([idl.TransformStamped(idl.Hdr(idl.Time(0, 0), "map"), "odom", idl.Transform(
            idl.Vec(0, math.inf, 0), idl.Quat(0, 0, 0, 1)))]).serialize())


# -- costmap values (Nav2 InflationLayer::computeCost + Costmap2DPublisher translation) ------------
def _compute_cost(d: float, k: float, r_in: float, r_inf: float) -> int:
    """A scalar restatement of Nav2's computeCost on the 0–255 scale, d in metres."""
    if d <= 0:
        return 254
    if d <= r_in:
        return 253
    if d > r_inf:
        return 0
    return int(252 * math.exp(-k * (d - r_in)))


@settings(max_examples=200, deadline=None)
@given(st.floats(-2, 2), st.floats(0.1, 50), st.floats(0, 0.3), st.floats(0.3, 2))
def test_nav2_cost_matches_compute_cost(d, k, r_in, r_inf):
    assert int(nav2_cost(np.array([d]), np.array([k]), r_in, r_inf)[0]) == _compute_cost(d, k, r_in, r_inf)


def test_costmap_conventions():
    esdf = wall_grid()
    data = costmap(esdf, {"high": 3.0, "mid": 6.0, "low": 10.0}, 10.0, 0.1, 0.55)
    d = esdf.distance[:, :, 0].astype(np.float64)  # the costmap compares in float64
    assert (d <= 0).sum() > 0 and (data == 100).any()
    np.testing.assert_array_equal(data == 100, d <= 0)
    np.testing.assert_array_equal(data == 99, (d > 0) & (d <= 0.1))
    assert ((data[(d > 0.1) & (d <= 0.55)] >= 1) & (data[(d > 0.1) & (d <= 0.55)] <= 98)).all()
    assert (data[d > 0.55] == 0).all()
    # Nearer the wall, never less cost (x grows towards it); the high-risk rows decay slowest.
    assert (np.diff(data.astype(int), axis=0) >= 0).all() and (np.diff(data.astype(int), axis=0) > 0).any()
    i = int(np.argmin(np.abs(d[:, 0] - 0.3)))
    assert data[i, 0] > data[i, 5] > data[i, 9] > 0
    assert int(nav2_cost(np.array([np.nan]), np.array([10.0]), 0.1, 0.55)[0]) == 255  # → −1 in the grid
    with pytest.raises(ValueError, match="nz = 1"):
        costmap(EsdfGrid(origin=(0, 0, 0), voxel_size=0.1, distance=np.ones((2, 2, 2), np.float32),
                         risk_group=np.zeros((2, 2, 2), np.uint8), groups=[], max_distance=2.0,
                         unknown_is_occupied=False), {}, 10.0, 0.1, 0.55)


# -- frames -----------------------------------------------------------------------------------------
def _yaw_q(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


@settings(max_examples=100, deadline=None)
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(-5, 5), st.floats(-5, 5), st.floats(-3, 3), st.floats(-5, 5),
       st.floats(-5, 5), st.floats(-2, 2))
def test_map_from_odom_composes_planar_poses(yaw_mo, yaw_ob, tx, ty, px, py, v, w):
    tr = Transform("map", "odom", (tx, ty, 0.0), _yaw_q(yaw_mo))
    o = Odometry(1, "odom", "base_link", (px, py, 0.0), _yaw_q(yaw_ob), (v, 0.0, 0.0), (0.0, 0.0, w))
    s = odometry_to_state(o, "map", tr)
    c, si = math.cos(yaw_mo), math.sin(yaw_mo)
    np.testing.assert_allclose(s.position, [c * px - si * py + tx, si * px + c * py + ty, 0], atol=1e-9)
    yaw = yaw_mo + yaw_ob
    assert math.isclose(math.cos(s.yaw), math.cos(yaw), abs_tol=1e-9)
    assert math.isclose(math.sin(s.yaw), math.sin(yaw), abs_tol=1e-9)
    np.testing.assert_allclose(s.linear_velocity, [v * math.cos(yaw), v * math.sin(yaw), 0], atol=1e-9)
    np.testing.assert_allclose(s.angular_velocity, [0, 0, w], atol=1e-9)
    assert s.header.frame_id == "map"


def test_a_state_is_never_relabelled():
    o = Odometry(12 * 10**9 + 345, "odom", "base_link", (1.0, 2.0, 0.0), _yaw_q(0.5), (0.4, 0, 0), (0, 0, 0.3))
    with pytest.raises(ValueError, match="'odom' is not the map frame 'map'"):
        odometry_to_state(o, "map")
    with pytest.raises(ValueError):
        odometry_to_state(o, "map", Transform("world", "odom", (0, 0, 0), (0, 0, 0, 1)))
    s = odometry_to_state(o, "odom")  # the ESDF is in odom: taken as is
    assert s.position == (1.0, 2.0, 0.0) and s.header.stamp_ns == 12 * 10**9 + 345
    np.testing.assert_allclose(s.linear_velocity, [0.4 * math.cos(0.5), 0.4 * math.sin(0.5), 0], atol=1e-12)


def test_state_to_tf_follows_rep105():
    st_ = RobotState(header=Header(frame_id="map", stamp_ns=9), position=(1, 2, 0), orientation=_yaw_q(0.3),
                     linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0))
    mo, ob = state_to_tf(st_, "odom", "base_link")
    assert (mo.parent, mo.child, mo.translation, mo.rotation) == ("map", "odom", (0, 0, 0), (0, 0, 0, 1))
    assert (ob.parent, ob.child, ob.translation) == ("odom", "base_link", (1, 2, 0))
    st_.header.frame_id = "odom"
    assert [(t.parent, t.child) for t in state_to_tf(st_, "odom", "base_link")] == [("odom", "base_link")]


# -- twist_mux arbitration ----------------------------------------------------------------------------
def test_twist_mux_priorities_and_timeouts():
    mux = CommandMux([MuxInput("nav", 10, 0.5), MuxInput("teleop", 100, 0.5)])
    offer = lambda m, name, now: m.admit(name, now) is None  # noqa: E731
    assert offer(mux, "nav", 0.0)                  # alone: forwarded
    assert offer(mux, "teleop", 0.1)               # higher priority takes over at once
    assert not offer(mux, "nav", 0.2)              # held while teleop is fresh
    assert not offer(mux, "nav", 0.6)              # teleop age 0.5: not yet expired (strictly greater)
    assert offer(mux, "nav", 0.61)                 # teleop expired: nav again
    assert offer(mux, "teleop", 0.7)
    same = CommandMux([MuxInput("a", 5, 0.5), MuxInput("b", 5, 0.5)])
    assert offer(same, "b", 0.0) and offer(same, "a", 0.1) and not offer(same, "b", 0.2)  # tie: first declared
    forever = CommandMux([MuxInput("nav", 10, 0.5), MuxInput("teleop", 100, 0.0)])
    offer(forever, "teleop", 0.0)
    assert not offer(forever, "nav", 1e6)          # a timeout of 0 never expires


def test_settings_are_strict():
    assert Ros2BridgeSettings().cmd_in_topic == "cmd_vel_smoothed"
    with pytest.raises(ValidationError, match="publish_tf"):
        Ros2BridgeSettings(publish_tf=True)
    Ros2BridgeSettings(publish_tf=True, odom_topic="")
    with pytest.raises(ValidationError):
        Ros2BridgeSettings(cmd_out_type="Twist3")
    with pytest.raises(ValidationError):
        Ros2BridgeSettings(teleop_priority=256)
    with pytest.raises(ValidationError, match="inscribed_radius"):
        Ros2BridgeSettings(inscribed_radius=1.0, inflation_radius=0.5)
    with pytest.raises(ValidationError, match="feed back"):
        Ros2BridgeSettings(cmd_vel_topic="cmd_vel_smoothed")
    with pytest.raises(ValidationError, match="must differ"):
        Ros2BridgeSettings(teleop_topic="cmd_vel_smoothed")


def test_core_sorts_bad_input_from_frame_mismatches():
    core = Ros2Bridge(Ros2BridgeSettings(max_cdr_bytes=2000))
    c = core.codec
    zero_q = c.encode_odometry(Odometry(0, "map", "base_link", (0, 0, 0), (0, 0, 0, 0), (0, 0, 0), (0, 0, 0)))
    with pytest.raises(ValueError, match="quaternion") as err:
        core.on_odometry(zero_q, 0.0)
    assert not isinstance(err.value, FrameMismatch)
    odom = c.encode_odometry(Odometry(0, "odom", "base_link", (0, 0, 0), (0, 0, 0, 1), (0, 0, 0), (0, 0, 0)))
    with pytest.raises(FrameMismatch):
        core.on_odometry(odom, 0.0)
    with pytest.raises(ValueError, match="unit quaternion"):
        core.on_tf(c.encode_tf([Transform("map", "odom", (0, 0, 0), (0, 0, 0, 0))]), False, 0.0)
    with pytest.raises(FrameMismatch):
        core.on_odometry(odom, 0.0)  # the bad transform was not kept
    with pytest.raises(CdrError, match="max_cdr_bytes"):
        core.on_tf(c.encode_tf([Transform("map", f"f{i}", (0, 0, 0), (0, 0, 0, 1)) for i in range(40)]), False, 0.0)


def test_core_watchdog_frames_and_tf_age():
    s = Ros2BridgeSettings(cmd_out_type="TwistStamped", teleop_topic="cmd_vel_teleop")
    core = Ros2Bridge(s)
    assert core.on_tick(0.0, 0) is not None  # nothing yet: zeros
    core.on_safe(_cmd((0.3, 0, 0), (0, 0, 0)), 1.0, 0)
    assert core.on_tick(1.1, 0) is None
    assert core.codec.decode_twist(core.on_tick(1.3, 0), "TwistStamped") == ((0, 0, 0), (0, 0, 0), "base_link")
    twist = core.codec.encode_twist(_cmd((0.5, 0, 0), (0, 0, 0)), "TwistStamped", 0, "odom")
    with pytest.raises(ValueError, match="body frame"):
        core.on_velocity("nav", "TwistStamped", twist, 0.0, 0)
    s2 = Ros2BridgeSettings()
    core = Ros2Bridge(s2)
    cmd = core.on_velocity("nav", "Twist", core.codec.encode_twist(_cmd((0.5, 0, 0), (0, 0, 0.1))), 0.0, 77)
    assert cmd.linear == (0.5, 0, 0) and cmd.source == "ros2/nav" and cmd.header.stamp_ns == 77
    odom = core.codec.encode_odometry(Odometry(0, "odom", "base_link", (1, 0, 0), (0, 0, 0, 1), (0, 0, 0), (0, 0, 0)))
    with pytest.raises(ValueError, match="no map → odom"):
        core.on_odometry(odom, 0.0)
    core.on_tf(core.codec.encode_tf([Transform("map", "odom", (2, 0, 0), (0, 0, 0, 1))]), False, 10.0)
    assert core.on_odometry(odom, 10.5).position == (3, 0, 0)
    with pytest.raises(ValueError):
        core.on_odometry(odom, 11.5)  # the dynamic map → odom is older than tf_timeout_s
    core.on_tf(core.codec.encode_tf([Transform("map", "odom", (2, 0, 0), (0, 0, 0, 1))]), True, 0.0)
    assert core.on_odometry(odom, 1e6).position == (3, 0, 0)  # a static one never ages
    core.on_esdf(wall_grid("odom"))  # the ESDF says the map frame is odom: no transform needed
    assert core.on_odometry(odom, 1e6).header.frame_id == "odom"
    bad_child = core.codec.encode_odometry(Odometry(0, "odom", "base_footprint", (1, 0, 0), (0, 0, 0, 1),
                                                    (0, 0, 0), (0, 0, 0)))
    with pytest.raises(ValueError, match="child frame"):
        core.on_odometry(bad_child, 0.0)
    assert ros_key("/limo1/", "cmd_vel") == "limo1/cmd_vel" and ros_key("", "/tf") == "tf"


# -- the node over a real router ----------------------------------------------------------------------
def garbage(valid: bytes, n: int, seed: int) -> list[bytes]:
    """Payloads no ROS type accepts: random bytes, truncations, a wrong encapsulation, and
    valid bytes plus junk. Deterministic."""
    rng = np.random.default_rng(seed)
    out = [b"", b"\x01\x02", valid[:4], valid[:-1], b"\x07\x07" + valid[2:], valid + b"\x00" * 9]
    while len(out) < n:
        kind = len(out) % 3
        if kind == 0:
            out.append(rng.bytes(int(rng.integers(0, 300))))
        elif kind == 1:
            out.append(valid[: int(rng.integers(0, len(valid)))])
        else:
            out.append(b"\x00\x01\x00\x00" + rng.bytes(int(rng.integers(0, 40))))
    return out


def _extra(status: Collector, key: str) -> float:
    return status.items[-1].extra.get(key, 0.0) if status.items else 0.0


def test_bridge_node_over_zenoh_serves_through_garbage(router_endpoint):
    robot, ns = "t_ros", "t_ns"
    codec = RosCodec("jazzy")
    args = ["--robot", robot, "--set", f"namespace={ns}", "--set", "teleop_topic=cmd_vel_teleop",
            "--set", "cmd_out_type=TwistStamped", "--set", "status_period_s=0.1"]
    with ServiceProcess("ros2-bridge", router_endpoint, args) as bridge, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/ros2-bridge"), bridge.output
        twists = Collector(s, f"{ns}/cmd_vel")
        refs = Collector(s, f"rf/{robot}/cmd/ref/**", VelocityCommand)
        states = Collector(s, f"rf/{robot}/state", RobotState)
        status = Collector(s, f"rf/{robot}/status/ros2-bridge", NodeStatus)
        zeros = twists.wait(1)  # no cmd/safe yet: the watchdog streams zero TwistStampeds
        assert codec.decode_twist(zeros[0], "TwistStamped") == ((0, 0, 0), (0, 0, 0), "base_link")
        cmd = _cmd((0.3, 0, 0), (0, 0, 0.2))
        twists.clear()
        put(s, f"rf/{robot}/cmd/safe", cmd)
        assert wait_until(lambda: any(codec.decode_twist(t, "TwistStamped")[0] == (0.3, 0, 0) for t in twists.items))

        valid = {
            "cmd_vel_smoothed": codec.encode_twist(_cmd((0.5, 0, 0), (0, 0, 0))),
            "cmd_vel_teleop": codec.encode_twist(_cmd((0.1, 0, 0), (0, 0, 0))),
            "odom": codec.encode_odometry(Odometry(0, "map", "base_link", (1.0, 2.0, 0.0), (0, 0, 0, 1),
                                                   (0, 0, 0), (0, 0, 0))),
            "tf": codec.encode_tf([Transform("map", "odom", (0, 0, 0), (0, 0, 0, 1))]),
            "tf_static": codec.encode_tf([Transform("map", "odom", (0, 0, 0), (0, 0, 0, 1))]),
        }
        counters = {"cmd_vel_smoothed": "nav_invalid", "cmd_vel_teleop": "teleop_invalid", "odom": "odom_invalid",
                    "tf": "tf_invalid", "tf_static": "tf_invalid"}
        sent: dict[str, int] = {}
        for i, (topic, good) in enumerate(valid.items()):
            junk = garbage(good, 40, seed=i)
            for payload in junk:
                s.put(f"{ns}/{topic}", payload)
            sent[topic] = len(junk)

        def settled() -> bool:
            if not status.items:
                return False
            st_ = status.items[-1]
            received = {t: st_.received.get(f"{ns}/{t}", 0) for t in sent}
            received["tf_static"] = int(st_.extra.get("tf_static_received", 0))  # an AdvancedSubscriber
            if received != sent:
                return False
            latest = all(st_.extra.get(counters[t], 0) + st_.dropped.get(f"{ns}/{t}", 0) == sent[t]
                         for t in ("cmd_vel_smoothed", "cmd_vel_teleop", "odom"))
            return latest and st_.extra.get("tf_invalid", 0) == sent["tf"] + sent["tf_static"]  # FIFO: none dropped

        # Every bad sample is either rejected (counted) or superseded in a latest-value queue (counted).
        assert wait_until(settled, 20), (status.items[-1] if status.items else None, bridge.output[-2000:])
        assert all(_extra(status, counters[t]) >= 1 for t in sent)
        # Still serving: the next valid sample of each kind goes through.
        s.put(f"{ns}/odom", valid["odom"])
        assert states.wait(1)[0].position == (1.0, 2.0, 0.0)
        s.put(f"{ns}/cmd_vel_smoothed", valid["cmd_vel_smoothed"])
        assert refs.wait(1)[0].linear == (0.5, 0, 0)
        s.put(f"{ns}/cmd_vel_teleop", valid["cmd_vel_teleop"])
        assert wait_until(lambda: any(r.source == "ros2/teleop" for r in refs.items))
        s.put(f"{ns}/cmd_vel_smoothed", valid["cmd_vel_smoothed"])  # teleop is fresh: nav is held back
        assert wait_until(lambda: _extra(status, "nav_preempted") >= 1)
        assert refs.items[-1].source == "ros2/teleop"
        assert refs.keys[-1] == f"rf/{robot}/cmd/ref/ros2/teleop"  # its own key (protocol.keys.REF_SOURCES)
        assert "rejected a Twist" in bridge.output and "rejected an Odometry" in bridge.output
        # One log line per rate-limit period, not one per bad sample.
        assert bridge.output.count("rejected an Odometry") < 10
        assert bridge.alive() and bridge.stop() == 0
        for c in (twists, refs, states, status):
            c.close()


def test_bridge_node_rejects_hostile_msgpack_and_publishes_rep105_tf(router_endpoint):
    """The riskfield-side keys (cmd/safe, map/esdf, safety/status, state) take hostile msgpack and
    the node keeps serving; with publish_tf, riskfield's state becomes odom → base_link (+ map → odom)."""
    from riskfield.testing import hostile_payloads

    robot, ns = "t_ros_tf", "t_ns_tf"
    codec = RosCodec("jazzy")
    args = ["--robot", robot, "--set", f"namespace={ns}", "--set", "publish_tf=true", "--set", "odom_topic=",
            "--set", "status_period_s=0.1"]
    st_ = RobotState(header=Header(frame_id="map"), position=(1.0, 2.0, 0.0), orientation=_yaw_q(0.4),
                     linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0))
    status_msg = SafetyStatus(h=0.3, risk_group=0, intervening=False, fallback=None, solve_us=1.0, esdf_age_ms=1.0)
    valid = {"cmd/safe": _cmd((0.2, 0, 0), (0, 0, 0)), "map/esdf": wall_grid(), "safety/status": status_msg,
             "state": st_}
    with ServiceProcess("ros2-bridge", router_endpoint, args) as bridge, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/ros2-bridge"), bridge.output
        status = Collector(s, f"rf/{robot}/status/ros2-bridge", NodeStatus)
        tfs = Collector(s, f"{ns}/tf")
        grids = Collector(s, f"{ns}/riskfield/costmap")
        diags = Collector(s, f"{ns}/diagnostics")
        status.wait(1)  # the node runs (its subscriptions are declared after its liveliness token)
        n = 150
        for k, msg in valid.items():
            for payload in hostile_payloads(msg, n=n, seed=3):
                put(s, f"rf/{robot}/{k}", payload)

        def settled() -> bool:
            if not status.items:
                return False
            last = status.items[-1]
            return all(last.received.get(k, 0) == n and last.invalid.get(k, 0) + last.dropped.get(k, 0) == n
                       for k in valid)

        assert wait_until(settled, 30), (status.items[-1].model_dump(exclude={"header"}) if status.items else None)
        assert all(status.items[-1].invalid.get(k, 0) >= 1 for k in valid)
        assert not tfs.items and not grids.items and not diags.items  # nothing bad got through
        for k, msg in valid.items():
            put(s, f"rf/{robot}/{k}", msg)
        mo, ob = codec.decode_tf(tfs.wait(1)[0])
        assert (mo.parent, mo.child, mo.translation, mo.rotation) == ("map", "odom", (0, 0, 0), (0, 0, 0, 1))
        assert (ob.parent, ob.child, ob.translation) == ("odom", "base_link", (1.0, 2.0, 0.0))
        assert np.allclose(ob.rotation, _yaw_q(0.4))
        grid = codec.ts.deserialize_cdr(grids.wait(1)[0], "nav_msgs/msg/OccupancyGrid")
        assert grid.info.width == 31 and (grid.data == 100).any()
        assert codec.decode(diags.wait(1)[0], "diagnostic_msgs/msg/DiagnosticArray").status[0].level == 0
        assert bridge.alive() and bridge.stop() == 0
        for c in (status, tfs, grids, diags):
            c.close()
