"""Robot kinematics: exact integration, platform limits, acceleration limits, each motion mode."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol.platforms import LIMO as LIMO_PLATFORM
from riskfield.services.simulator.robots import (
    LIMO,
    AckermannPlant,
    DifferentialPlant,
    MecanumPlant,
    PlanarLimits,
    PointMassPlant,
    VelocityPointPlant,
    make_robot,
    se2_step,
)

FREE = PlanarLimits(v_max=1e9, vy_max=1e9, w_max=1e9, a_max=1e9, alpha_max=1e9)


def cmd(v=0.0, w=0.0, vy=0.0, vz=0.0):
    return np.array([v, vy, vz]), np.array([0.0, 0.0, w])


@settings(max_examples=60, deadline=None)
@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(-3, 3), st.floats(-math.pi, math.pi), st.floats(0.001, 0.5))
def test_se2_step_matches_fine_euler_integration(vx, vy, w, yaw, dt):
    x, y, th = 0.0, 0.0, yaw
    n = 4000
    for _ in range(n):  # midpoint rule: second order
        mid = th + 0.5 * w * dt / n
        x += (math.cos(mid) * vx - math.sin(mid) * vy) * dt / n
        y += (math.sin(mid) * vx + math.cos(mid) * vy) * dt / n
        th += w * dt / n
    ex, ey, eth = se2_step(0.0, 0.0, yaw, vx, vy, w, dt)
    assert ex == pytest.approx(x, abs=1e-7) and ey == pytest.approx(y, abs=1e-7)
    assert math.cos(eth - th) == pytest.approx(1.0, abs=1e-9)


def test_unicycle_drives_a_circle_of_radius_v_over_w():
    r = DifferentialPlant(limits=FREE)
    for _ in range(1000):  # one full turn: ω = 0.5π rad/s for 4 s
        r.step(*cmd(0.5, 0.5 * math.pi), 0.004)
    assert r.x == pytest.approx(0.0, abs=1e-9) and r.y == pytest.approx(0.0, abs=1e-9)
    r2 = DifferentialPlant(limits=FREE)
    for _ in range(500):  # half a turn: at the far side of the circle, 2·v/ω away
        r2.step(*cmd(0.5, 0.5 * math.pi), 0.004)
    assert math.hypot(r2.x, r2.y) == pytest.approx(2 * 0.5 / (0.5 * math.pi), abs=1e-9)


def test_limo_clamps_speed_and_yaw_rate_and_limits_acceleration():
    r = DifferentialPlant()
    r.step(*cmd(5.0, 10.0), 0.1)
    assert r.vx == pytest.approx(LIMO.a_max * 0.1) and r.w == pytest.approx(LIMO.alpha_max * 0.1)
    for _ in range(200):
        r.step(*cmd(5.0, 10.0), 0.01)
    assert r.vx == pytest.approx(LIMO.v_max) and r.w == pytest.approx(LIMO.w_max)
    st_ = r.state()
    assert np.linalg.norm(st_.linear_velocity) == pytest.approx(LIMO.v_max)
    assert np.linalg.norm(st_.orientation) == pytest.approx(1.0)
    # Braking from full speed takes v_max / a_max.
    steps = 0
    while r.vx > 0:
        r.step(*cmd(0.0, 0.0), 0.01)
        steps += 1
    assert steps * 0.01 == pytest.approx(LIMO.v_max / LIMO.a_max, abs=0.011)


def test_unicycle_ignores_lateral_commands_and_brakes_on_nan():
    r = DifferentialPlant(limits=FREE)
    r.step(np.array([0.0, 1.0, 0.0]), np.zeros(3), 0.1)
    assert r.y == 0.0 and r.x == 0.0
    r.step(*cmd(0.5), 0.1)
    r.step(np.array([np.nan, 0, 0]), np.zeros(3), 0.1)
    assert r.vx == 0.0  # FREE limits: immediate stop on garbage


def test_ackermann_respects_minimum_turning_radius_and_cannot_turn_in_place():
    """The kinematic bicycle's limit is the central angle at the inner wheel's limit (the LIMO's
    0.488 rad inner angle is ~0.408 rad central): the radius is the chassis's, ~0.46 m."""
    r = AckermannPlant(limits=FREE)
    assert r.max_steer == pytest.approx(LIMO_PLATFORM.max_central_steering) and 0.40 < r.max_steer < 0.41
    assert r.min_turning_radius == pytest.approx(LIMO_PLATFORM.min_turning_radius)
    assert 0.45 < r.min_turning_radius < 0.47
    for _ in range(100):
        r.step(*cmd(0.5, 10.0), 0.01)  # asks for a much tighter turn than possible
    assert r.steer == pytest.approx(r.max_steer)
    assert 0.5 / r.w == pytest.approx(r.min_turning_radius)
    r2 = AckermannPlant(limits=FREE)
    r2.step(*cmd(0.0, 1.0), 0.5)
    assert r2.yaw == 0.0 and r2.w == 0.0
    r3 = AckermannPlant(limits=FREE)
    r3.step(*cmd(0.5, 0.3), 0.01)  # feasible: turns at the commanded rate
    assert r3.w == pytest.approx(0.3)


def test_mecanum_moves_sideways():
    r = MecanumPlant()
    for _ in range(300):
        r.step(*cmd(0.0, 0.0, vy=0.5), 0.01)
    assert r.x == pytest.approx(0.0, abs=1e-12) and r.y > 1.0 and r.yaw == 0.0
    assert r.state().linear_velocity[1] == pytest.approx(0.5)


def test_single_integrator_norm_limit_and_yaw_rotation():
    r = VelocityPointPlant(v_max=1.0, yaw=math.pi / 2)
    r.step(np.array([3.0, 0.0, 4.0]), np.zeros(3), 1.0)  # body x is world y
    np.testing.assert_allclose(r.p, [0.0, 0.6, 0.8], atol=1e-12)


def test_double_integrator_exact_under_constant_acceleration():
    r = PointMassPlant(input="acceleration", a_max=10.0, v_max=100.0)
    for _ in range(100):
        r.step(np.array([1.0, 0.0, 2.0]), np.zeros(3), 0.01)
    np.testing.assert_allclose(r.p, [0.5, 0.0, 1.0], atol=1e-12)  # ½at², t = 1
    np.testing.assert_allclose(r.v, [1.0, 0.0, 2.0], atol=1e-12)
    r2 = PointMassPlant(input="acceleration", a_max=1.0)
    r2.step(np.array([3.0, 4.0, 0.0]), np.zeros(3), 1.0)
    assert np.linalg.norm(r2.v) == pytest.approx(1.0)


def test_double_integrator_tracks_velocity_setpoint():
    r = PointMassPlant(input="velocity", a_max=3.0, v_max=2.0)
    for _ in range(300):
        r.step(np.array([0.5, 0.0, 0.0]), np.zeros(3), 0.01)
    np.testing.assert_allclose(r.v, [0.5, 0.0, 0.0], atol=1e-4)
    with pytest.raises(ValueError):
        PointMassPlant(input="jerk")


@pytest.mark.parametrize("kind", ["limo", "ackermann", "mecanum", "single_integrator", "double_integrator"])
def test_make_robot_starts_where_asked(kind):
    r = make_robot(kind, (1.0, -2.0, 0.5), z=0.3)
    s = r.state()
    np.testing.assert_allclose(s.position, [1.0, -2.0, 0.3])
    assert s.yaw == pytest.approx(0.5)
    np.testing.assert_allclose(r.pose()[:3, 3], [1.0, -2.0, 0.3])
    r.step(*cmd(0.3), 0.1)
    assert np.isfinite(r.state().position).all()


def test_make_robot_rejects_unknown():
    with pytest.raises(ValueError):
        make_robot("tank")
    with pytest.raises(ValueError):
        make_robot("limo", wheelbase=0.3)
    assert make_robot("limo", v_max=0.5).limits.v_max == 0.5  # type: ignore[attr-defined]
