"""MAVLink conventions (NED/FRD ↔ ENU/FLU) and the bridge's schedule, without I/O."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from riskfield.edge.mavlink.bridge import Heartbeat, MavlinkBridge, MavlinkConfig, RequestInterval, SetpointOut
from riskfield.edge.mavlink.convert import (
    MAV_FRAME_BODY_NED,
    MAV_FRAME_LOCAL_NED,
    VELOCITY_YAWRATE_MASK,
    VelocityLimits,
    attitude_ned_frd_to_enu_flu,
    command_to_setpoint,
    vehicle_state,
)
from riskfield.services.geometry.transforms import euler_zyx_matrix, matrix_to_quat

angle = st.floats(-math.pi, math.pi)
small = st.floats(-1.2, 1.2)  # pitch away from gimbal lock


def quat_to_matrix(q: tuple[float, float, float, float]) -> np.ndarray:
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def test_type_mask_selects_velocity_and_yaw_rate() -> None:
    ignored = {i for i in range(12) if VELOCITY_YAWRATE_MASK >> i & 1}
    assert ignored == {0, 1, 2, 6, 7, 8, 10}  # position, acceleration, yaw ignored; vx vy vz, yaw rate used


def test_body_flu_to_frd_setpoint() -> None:
    sp = command_to_setpoint((0.5, 0.2, 0.1), 0.3, VelocityLimits())
    assert (sp.vx, sp.vy, sp.vz, sp.yaw_rate) == pytest.approx((0.5, -0.2, -0.1, -0.3))
    assert sp.frame == MAV_FRAME_BODY_NED and sp.type_mask == 0x5C7


def test_local_ned_setpoint_uses_the_attitude() -> None:
    r = euler_zyx_matrix(0.0, 0.0, math.pi / 2)  # facing east
    sp = command_to_setpoint((0.5, 0.0, 0.0), 0.0, VelocityLimits(), MAV_FRAME_LOCAL_NED, r)
    assert (sp.vx, sp.vy) == pytest.approx((0.0, 0.5), abs=1e-12)  # forward = east
    unknown = command_to_setpoint((0.5, 0.0, 0.0), 0.0, VelocityLimits(), MAV_FRAME_LOCAL_NED, None)
    assert unknown.is_zero
    with pytest.raises(ValueError):
        command_to_setpoint((0.5, 0.0, 0.0), 0.0, VelocityLimits(), 3)


@given(small, small, small, small)
def test_limits_scale_uniformly(vx: float, vy: float, vz: float, wz: float) -> None:
    lim = VelocityLimits(max_horizontal=0.5, max_vertical=0.2, max_yaw_rate=0.4)
    sp = command_to_setpoint((3 * vx, 3 * vy, 3 * vz), 3 * wz, lim)
    assert math.hypot(sp.vx, sp.vy) <= lim.max_horizontal + 1e-9
    assert abs(sp.vz) <= lim.max_vertical + 1e-9 and abs(sp.yaw_rate) <= lim.max_yaw_rate + 1e-9
    # One scale for every axis: (vx, −wz) and the setpoint's (vx, yaw rate) are parallel (a cross
    # product, not a ratio: a subnormal vx scales to 0.0).
    assert sp.yaw_rate * vx + wz * sp.vx == pytest.approx(0.0, abs=1e-12)


def test_non_finite_command_is_zero() -> None:
    assert command_to_setpoint((math.nan, 0.0, 0.0), 0.0, VelocityLimits()).is_zero


def test_north_facing_vehicle_has_enu_yaw_pi_over_2() -> None:
    st_ = vehicle_state((10.0, 2.0, -3.0), (1.0, 0.0, -0.5), (0.0, 0.0, 0.0), (0.0, 0.0, 0.2))
    assert st_.position == pytest.approx((2.0, 10.0, 3.0))  # north 10 → y 10, 3 m up
    assert st_.linear_velocity == pytest.approx((0.0, 1.0, 0.5))
    _, _, z, w = st_.orientation
    assert 2 * math.atan2(z, w) == pytest.approx(math.pi / 2)
    assert st_.angular_velocity == pytest.approx((0.0, 0.0, -0.2))  # clockwise NED yaw rate → −ωz ENU


@given(angle, small, angle)
def test_attitude_conversion_keeps_body_axes(roll: float, pitch: float, yaw: float) -> None:
    r_ned = euler_zyx_matrix(roll, pitch, yaw)
    r_enu = attitude_ned_frd_to_enu_flu(roll, pitch, yaw)
    assert np.allclose(r_enu.T @ r_enu, np.eye(3), atol=1e-9) and np.linalg.det(r_enu) == pytest.approx(1.0)
    swap = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    assert np.allclose(r_enu[:, 0], swap @ r_ned[:, 0])  # forward axis is forward in both
    assert np.allclose(r_enu[:, 1], -(swap @ r_ned[:, 1]))  # left = −right
    assert np.allclose(r_enu[:, 2], -(swap @ r_ned[:, 2]))  # up = −down
    q = matrix_to_quat(r_enu)
    assert np.allclose(quat_to_matrix(q), r_enu, atol=1e-9)
    if abs(roll) < 1e-9 and abs(pitch) < 1e-9:
        assert math.atan2(r_enu[1, 0], r_enu[0, 0]) == pytest.approx(
            (math.pi / 2 - yaw + math.pi) % (2 * math.pi) - math.pi, abs=1e-9)


@given(angle)
def test_level_yaw_relation(yaw: float) -> None:
    r = attitude_ned_frd_to_enu_flu(0.0, 0.0, yaw)
    got = math.atan2(r[1, 0], r[0, 0])
    want = math.pi / 2 - yaw
    assert math.cos(got - want) == pytest.approx(1.0)


# -- bridge schedule --------------------------------------------------------------------------


def bridge() -> MavlinkBridge:
    b = MavlinkBridge(MavlinkConfig(setpoint_hz=20, watchdog_s=0.2, interval_retry_s=5.0))
    b.on_heartbeat(1, 1, 10, 12, 0.0)
    return b


def test_config_refuses_slow_setpoints() -> None:
    with pytest.raises(ValueError):
        MavlinkConfig(setpoint_hz=5)


def test_heartbeat_at_1hz_and_setpoints_at_rate() -> None:
    b = bridge()
    hb = sps = 0
    for i in range(200):  # 2 s at 100 Hz
        out = b.tick(i * 0.01)
        hb += sum(isinstance(o, Heartbeat) for o in out)
        sps += sum(isinstance(o, SetpointOut) for o in out)
    assert hb == 2 and 38 <= sps <= 41


def test_gcs_heartbeats_are_not_vehicles() -> None:
    b = MavlinkBridge()
    b.on_heartbeat(200, 190, 6, 8, 0.0)
    assert b.target is None
    assert not any(isinstance(o, SetpointOut) for o in b.tick(1.0))  # nobody to address
    b.on_heartbeat(3, 1, 10, 3, 1.0)
    assert b.target == (3, 1) and b.autopilot == 3


def test_command_is_sent_at_once_then_zero_when_stale() -> None:
    b = bridge()
    b.tick(0.0)
    out = b.on_command((0.4, 0.0, 0.0), 0.1, 1.0)
    assert out is not None and out.setpoint.vx == pytest.approx(0.4) and out.target_system == 1
    assert out.time_boot_ms == 1000
    (sp,) = [o for o in b.tick(1.06) if isinstance(o, SetpointOut)]
    assert sp.setpoint.vx == pytest.approx(0.4)
    (sp,) = [o for o in b.tick(1.25) if isinstance(o, SetpointOut)]
    assert sp.setpoint.is_zero and b.counters.watchdog_stops == 1
    assert b.shutdown(1.3).setpoint.is_zero


def test_stream_intervals_are_requested_until_state_arrives() -> None:
    b = bridge()
    reqs = [o for o in b.tick(0.0) if isinstance(o, RequestInterval)]
    assert {r.message_id for r in reqs} == {30, 32} and reqs[0].interval_us == 33333
    assert not [o for o in b.tick(1.0) if isinstance(o, RequestInterval)]
    assert [o for o in b.tick(5.0) if isinstance(o, RequestInterval)]  # retried: nothing streams
    b.on_local_position(1, 2, 3, 0, 0, 0, 10.0)
    b.on_attitude(0, 0, 0, 0, 0, 0, 10.0)
    assert b.state(10.0) is not None
    assert not [o for o in b.tick(10.1) if isinstance(o, RequestInterval)]  # streaming: no more requests
    assert b.state(11.0) is None  # stale


def test_non_finite_vehicle_data_is_ignored() -> None:
    b = bridge()
    b.on_local_position(math.nan, 0, 0, 0, 0, 0, 0.0)
    b.on_attitude(0, 0, 0, 0, 0, 0, 0.0)
    assert b.state(0.0) is None
