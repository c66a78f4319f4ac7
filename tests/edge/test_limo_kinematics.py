"""LIMO kinematics: per-mode motion frames, limits by uniform scaling, dead reckoning."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from riskfield.edge.limo import ackermann
from riskfield.edge.limo.kinematics import (
    LimoLimits,
    MotionMode,
    WheelOdometry,
    command_to_motion,
    steering_angle,
)

L = LimoLimits()
speed = st.floats(-5, 5, allow_nan=False)


def test_differential_passes_small_commands_through() -> None:
    m = command_to_motion(0.3, 0.2, 0.5, MotionMode.DIFFERENTIAL, L)
    assert (m.linear, m.angular, m.lateral, m.steering) == (0.3, 0.5, 0.0, 0.0)


@given(speed, speed, speed, st.sampled_from(list(MotionMode)))
def test_limits_hold_and_direction_is_kept(vx: float, vy: float, wz: float, mode: MotionMode) -> None:
    m = command_to_motion(vx, vy, wz, mode, L)
    assert abs(m.linear) <= L.max_linear + 1e-12
    assert abs(m.lateral) <= L.max_lateral + 1e-12
    assert abs(m.angular) <= L.max_angular + 1e-12
    assert abs(ackermann.inner_from_command_field(m.steering)) <= L.max_steering + 1e-12
    if mode == MotionMode.DIFFERENTIAL:
        wheel = abs(m.linear) + abs(m.angular) * L.track / 2
        assert wheel <= L.max_wheel_speed + 1e-9
        # Uniform scaling: (linear, angular) is λ·(vx, wz) with one λ in [0, 1], the largest the limits allow.
        # Each clause below is checked against the command, not against a λ read back from the output.
        assert m.linear * wz == pytest.approx(m.angular * vx, abs=1e-9)  # parallel to the command
        assert m.linear * vx >= 0 and m.angular * wz >= 0  # the same way round: λ ≥ 0
        assert abs(m.linear) <= abs(vx) + 1e-12 and abs(m.angular) <= abs(wz) + 1e-12  # λ ≤ 1
        passed = m.linear == pytest.approx(vx, abs=1e-12) and m.angular == pytest.approx(wz, abs=1e-12)
        bound = (abs(m.linear) == pytest.approx(L.max_linear, abs=1e-9)
                 or abs(m.angular) == pytest.approx(L.max_angular, abs=1e-9)
                 or wheel == pytest.approx(L.max_wheel_speed, abs=1e-9))
        assert passed or bound, "scaled down further than any limit asks"
    if mode == MotionMode.MECANUM:
        r = (L.track + L.wheelbase) / 2
        assert abs(m.linear) + abs(m.lateral) + abs(m.angular) * r <= L.max_wheel_speed + 1e-9
    if vx == 0:
        assert m.linear == 0


def test_scaling_is_uniform_not_per_axis() -> None:
    m = command_to_motion(2.0, 0.0, 1.0, MotionMode.DIFFERENTIAL, L)
    assert m.angular / m.linear == pytest.approx(0.5)


def test_ackermann_steering_from_the_bicycle_model() -> None:
    """The central angle follows the bicycle model; the frame carries the inner wheel's angle / 1.64
    (the vendor's values are checked in test_limo_conformance.py)."""
    v, w = 0.5, 0.5
    assert steering_angle(v, w, L) == pytest.approx(math.atan(w * L.wheelbase / v))
    m = command_to_motion(v, 0.0, w, MotionMode.ACKERMANN, L)
    assert m.linear == v and m.angular == 0.0
    assert 0 < m.steering < steering_angle(v, w, L)  # the field is not the central angle
    # Reversing while turning left: the wheels point right.
    assert steering_angle(-0.5, 0.5, L) < 0
    assert command_to_motion(-0.5, 0.0, 0.5, MotionMode.ACKERMANN, L).steering < 0


def test_ackermann_clamps_steering_and_cannot_turn_in_place() -> None:
    m = command_to_motion(0.2, 0.0, 3.0, MotionMode.ACKERMANN, L)
    assert ackermann.inner_from_command_field(m.steering) == pytest.approx(L.max_steering, abs=2e-3)
    assert ackermann.inner_from_command_field(m.steering) <= L.max_steering
    assert steering_angle(0.2, 3.0, L) == pytest.approx(L.max_central_steering)
    # The minimum turning radius at the inner wheel's limit is about the LIMO's 0.46 m.
    assert 1 / L.max_curvature == pytest.approx(0.46, abs=0.01)
    assert L.max_central_steering == pytest.approx(0.408, abs=1e-3)
    m0 = command_to_motion(0.0, 0.0, 1.0, MotionMode.ACKERMANN, L)
    assert m0.linear == 0 and m0.steering == 0


def test_mecanum_keeps_lateral_and_differential_drops_it() -> None:
    assert command_to_motion(0.1, 0.2, 0.0, MotionMode.MECANUM, L).lateral == pytest.approx(0.2)
    assert command_to_motion(0.1, 0.2, 0.0, MotionMode.DIFFERENTIAL, L).lateral == 0.0


def test_non_finite_command_becomes_a_stop() -> None:
    m = command_to_motion(math.nan, 0.0, math.inf, MotionMode.DIFFERENTIAL, L)
    assert m.is_stop


def test_motion_mode_parse() -> None:
    assert MotionMode.parse("ackermann") is MotionMode.ACKERMANN
    assert MotionMode.parse("2") is MotionMode.MECANUM
    with pytest.raises(KeyError):
        MotionMode.parse("tank")


def test_limits_must_be_positive() -> None:
    with pytest.raises(ValueError):
        LimoLimits(max_linear=0.0)


def test_odometry_straight_and_turning() -> None:
    odo = WheelOdometry(track=0.2)
    assert not odo.update_wheels(5.0, 5.0)  # first frame: reference only, counters are absolute
    for i in range(1, 11):
        odo.update_wheels(5.0 + 0.1 * i, 5.0 + 0.1 * i)
    assert (odo.x, odo.y, odo.yaw) == pytest.approx((1.0, 0.0, 0.0))
    # Turn in place by +90°: right wheel forward, left back by π/2 · track/2.
    arc = math.pi / 2 * 0.1
    odo.update_wheels(6.0 - arc, 6.0 + arc)
    assert odo.yaw == pytest.approx(math.pi / 2)
    odo.update_wheels(6.0 - arc + 0.5, 6.0 + arc + 0.5)
    assert (odo.x, odo.y) == pytest.approx((1.0, 0.5))


@given(st.lists(st.tuples(st.floats(-0.02, 0.02), st.floats(-0.02, 0.02)), min_size=1, max_size=100))
def test_odometry_arc_length_matches_wheel_travel(steps: list) -> None:
    """|displacement| never exceeds the summed centre travel (a property of any dead reckoning)."""
    odo = WheelOdometry(track=0.172)
    odo.update_wheels(0.0, 0.0)
    left = right = travel = 0.0
    for dl, dr in steps:
        left, right = left + dl, right + dr
        odo.update_wheels(left, right)
        travel += abs(dl + dr) / 2
    assert math.hypot(odo.x, odo.y) <= travel + 1e-9
    assert -math.pi <= odo.yaw < math.pi


def test_imu_yaw_replaces_wheel_heading_relative_to_the_first_reading() -> None:
    odo = WheelOdometry(track=0.2)
    odo.update_imu_yaw(1.0)  # IMU not aligned with the map: the first reading is heading 0
    odo.update_wheels(0.0, 0.0)
    odo.update_wheels(0.0, 0.2)  # wheels would say +1 rad, but the IMU says no rotation
    assert odo.yaw == pytest.approx(0.0)
    odo.update_imu_yaw(1.0 + math.pi / 2)
    odo.update_wheels(0.5, 0.7)
    assert odo.yaw == pytest.approx(math.pi / 2)
    assert odo.y == pytest.approx(0.5)


def test_odometry_rejects_jumps() -> None:
    odo = WheelOdometry(track=0.2)
    odo.update_wheels(0.0, 0.0)
    assert not odo.update_wheels(100.0, 100.0)
    assert odo.jumps == 1 and odo.x == 0.0
    assert odo.update_wheels(100.1, 100.1)  # the jump became the new reference
    assert odo.x == pytest.approx(0.1)
