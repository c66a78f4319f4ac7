"""The Ackermann conversions (``edge/limo/ackermann.py``) and the curvature-keeping limits."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from riskfield.edge.limo import ackermann as a
from riskfield.edge.limo.kinematics import (
    LimoLimits,
    MotionMode,
    ackermann_field,
    ackermann_velocity,
    command_to_motion,
)

L = LimoLimits()
WB, TR = L.wheelbase, L.track
central = st.floats(-1.2, 1.2, allow_nan=False)
speed = st.floats(-3, 3, allow_nan=False)


@given(central)
def test_central_and_inner_angles_convert_into_each_other(c: float) -> None:
    i = a.central_to_inner(c, WB, TR)
    assert math.copysign(1, i) == math.copysign(1, c) or c == 0
    assert abs(i) >= abs(c) - 1e-15  # the inner wheel turns more than the centre line
    assert a.inner_to_central(i, WB, TR) == pytest.approx(c, abs=1e-12)


@given(central)
def test_inner_angle_is_the_inner_wheels_radius(c: float) -> None:
    """tan i = L / (r − T/2) with r = L / tan c: the wheel on the inside of the turn (past a
    right angle when the centre's radius is below T/2)."""
    if abs(c) < 1e-6:
        return
    r = WB / math.tan(abs(c))
    assert abs(a.central_to_inner(c, WB, TR)) == pytest.approx(math.atan2(WB, r - TR / 2), rel=1e-9)


@given(st.floats(-0.5, 0.5, allow_nan=False))
def test_the_chassis_side_inverts_the_bridge_side(inner: float) -> None:
    assert a.inner_from_command_field(a.steering_field(inner)) == pytest.approx(inner, abs=1e-15)
    assert a.inner_from_feedback_field(a.feedback_field(inner)) == pytest.approx(inner, abs=1e-15)


def test_the_feedback_scale_depends_on_the_sign() -> None:
    assert a.inner_from_feedback_field(0.1) == pytest.approx(0.247)
    assert a.inner_from_feedback_field(-0.1) == pytest.approx(-0.164)
    assert a.inner_from_feedback_field(0.0) == 0.0
    assert a.steering_field(0.247) == pytest.approx(0.247 / 1.64)  # the command: 1.64 whatever the sign


def test_min_radius_and_central_limit_agree() -> None:
    r = a.min_turning_radius(WB, TR, L.max_steering)
    assert WB / math.tan(a.max_central_angle(WB, TR, L.max_steering)) == pytest.approx(r)


@given(speed, st.floats(-20, 20, allow_nan=False))
def test_ackermann_limits_keep_the_curvature_or_drive_the_limit_circle(vx: float, wz: float) -> None:
    v, w = ackermann_velocity(vx, wz, L)
    assert abs(v) <= min(abs(vx), L.max_linear) + 1e-12
    assert v == 0 or math.copysign(1, v) == math.copysign(1, vx)
    assert abs(w) <= L.max_angular + 1e-12
    assert abs(v) + abs(w) * TR / 2 <= L.max_wheel_speed + 1e-9
    if abs(vx) < L.min_speed_for_steering:
        assert w == 0.0
        return
    kappa, kmax = wz / vx, L.max_curvature
    if abs(kappa) <= kmax:
        assert w == pytest.approx(v * kappa, rel=1e-9, abs=1e-12)  # the radius is kept
    else:
        assert w == pytest.approx(math.copysign(kmax, kappa) * v, rel=1e-9, abs=1e-12)  # the limit circle
    # The frame steers that curvature (to the field's 0.001 step, towards zero).
    field = ackermann_field(v, w, L)
    c = a.inner_to_central(a.inner_from_command_field(field), WB, TR)
    want = math.atan(WB * w / v) if v else 0.0
    assert abs(c) <= abs(want) + 1e-12
    assert c == pytest.approx(want, abs=1.7e-3)


def test_a_speed_clamp_scales_the_yaw_rate_with_it() -> None:
    """v = 2, ω = 1 (r = 2 m): the wheel speed 2 + 1·T/2 = 2.086 binds, λ = 1 / 2.086 = 0.479386:
    (0.958773, 0.479386), still r = 2 m; the steering field is that of r = 2 m,
    i = atan(0.2 / (2 − 0.086)) = 0.104115, / 1.64 = 0.063485 → 0.063."""
    v, w = ackermann_velocity(2.0, 1.0, L)
    assert (v, w) == pytest.approx((0.958773, 0.479386), abs=1e-6)
    m = command_to_motion(2.0, 0.0, 1.0, MotionMode.ACKERMANN, L)
    assert m.linear == pytest.approx(v) and m.angular == 0.0 and m.steering == pytest.approx(0.063)
