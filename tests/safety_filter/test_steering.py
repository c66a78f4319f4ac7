"""An Ackermann chassis drives only what it can steer: the filter passes on a command whose turn is
tighter than the chassis's tightest circle only as the chassis will drive it, and only if the barrier
passes that one too (``supervisor``: ``steering = "ackermann"``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from riskfield.edge.limo.kinematics import LimoLimits, MotionMode, ackermann_velocity, command_to_motion
from riskfield.protocol import RobotState, VelocityCommand
from riskfield.protocol.platforms import LIMO, ackermann_steerable
from riskfield.services.fields import AnalyticField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Sphere
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.state import FilterState
from riskfield.services.safety_filter.supervisor import UNSTEERABLE, FilterSupervisor

GROUPS = ["high", "mid", "low"]
KAPPA = LIMO.max_curvature
#: Obstacles around the start: one ahead-left, one to the right, one behind (furniture, the low group).
SCENE = [Sphere([0.75, 0.45, 0.0], 0.2, planar=True, label=3), Sphere([0.3, -0.65, 0.0], 0.25, planar=True, label=3),
         Sphere([-0.8, 0.0, 0.0], 0.3, planar=True, label=3)]


def grid():
    field = AnalyticField(SCENE, groups=GROUPS)
    return to_grid_message(to_esdf(field, [-2.0, -2.0, 0.0], [2.0, 2.0, 0.0], 0.05, planar=True))


GRID = grid()


_FILTERS: dict[str, SafetyFilter] = {}


def supervisor(steering: str) -> FilterSupervisor:
    """A fresh supervisor round one filter per steering mode (its compiled step loads once)."""
    if steering not in _FILTERS:
        _FILTERS[steering] = SafetyFilter(FilterConfig(steering=steering))
    return FilterSupervisor(_FILTERS[steering], 0.3, 0.3, 0.2)


def tick(sup: FilterSupervisor, v: float, w: float, x: float = 0.0, y: float = 0.0, yaw: float = 0.0,
         speed: float = 0.0):
    sup.on_map(GRID, 0.0)
    sup.on_state(RobotState(position=(x, y, 0.0), orientation=(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
                            linear_velocity=(speed * math.cos(yaw), speed * math.sin(yaw), 0.0),
                            angular_velocity=(0.0, 0.0, 0.0)), 0.0)
    sup.on_ref(VelocityCommand(linear=(v, 0.0, 0.0), angular=(0.0, 0.0, w), source="joystick"), 0.0)
    return sup.tick(0.01)


def passes(sup: FilterSupervisor, cmd: VelocityCommand, x: float, y: float, yaw: float, speed: float) -> bool:
    """The filter's own verdict on a command: every row holds for it (it comes out unchanged)."""
    s = FilterState.planar(x, y, yaw, velocity=(speed * math.cos(yaw), speed * math.sin(yaw), 0.0))
    lin, ang = np.array(cmd.linear), np.array(cmd.angular)
    res = sup.filter.filter(s, sup.filter.model.reference(lin, ang, s), sup.guard.field(sup._slots["map"].value), ang)
    return res.fallback is None and not res.intervening


def test_in_open_space_a_tight_turn_becomes_the_tightest_circle_at_the_same_speed():
    cmd, status = tick(supervisor("differential"), 0.3, 1.5, x=-0.1)
    assert cmd.angular[2] == pytest.approx(1.5) and not status.steering_limited  # a skid-steer turns so
    cmd, status = tick(supervisor("ackermann"), 0.3, 1.5, x=-0.1)
    assert status.fallback is None and status.steering_limited
    assert cmd.linear[0] == pytest.approx(0.3) and cmd.angular[2] == pytest.approx(0.3 * KAPPA)
    # Standing still it cannot turn at all: turning on the spot is no command for it.
    cmd, status = tick(supervisor("ackermann"), 0.0, 1.0, x=-0.1)
    assert cmd.angular[2] == 0.0 and status.fallback is None


@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(x=st.floats(-0.3, 0.3), y=st.floats(-0.25, 0.25), yaw=st.floats(-math.pi, math.pi), speed=st.floats(0.0, 0.6),
       v=st.floats(-0.6, 0.8), w=st.floats(-2.0, 2.0))
def test_what_an_ackermann_robot_is_sent_it_can_steer_and_the_filter_passes(x, y, yaw, speed, v, w):
    sup = supervisor("ackermann")
    cmd, status = tick(sup, v, w, x, y, yaw, speed)
    v_out, w_out = cmd.linear[0], cmd.angular[2]
    if status.fallback not in (None, "slack"):
        assert (v_out, w_out) == (0.0, 0.0)  # a brake
        return
    # The chassis drives exactly this command: what the filter certified is the path driven.
    assert ackermann_steerable(v_out, w_out, KAPPA, LIMO.min_steering_speed) == pytest.approx((v_out, w_out), abs=1e-9)
    if status.steering_limited:
        assert passes(sup, cmd, x, y, yaw, speed)


def test_a_turn_the_chassis_cannot_steer_past_an_obstacle_brakes_and_says_why():
    """Furniture ahead-left and to the right, and a full turn at 0.5 m/s: at some headings the
    skid-steer's turn passes the barrier while the LIMO's tightest circle at that speed does not,
    and there the filter brakes, saying ``unsteerable``."""
    found = []
    for yaw in np.linspace(-0.6, 0.6, 25):
        for w in (-2.0, 2.0):
            _, st_d = tick(supervisor("differential"), 0.5, w, 0.0, 0.0, float(yaw), 0.5)
            cmd_a, st_a = tick(supervisor("ackermann"), 0.5, w, 0.0, 0.0, float(yaw), 0.5)
            if st_d.fallback is None and st_a.fallback == UNSTEERABLE:
                found.append((yaw, w))
                assert cmd_a.linear == (0.0, 0.0, 0.0) and cmd_a.angular == (0.0, 0.0, 0.0)
    assert found, "no pose where the substitute fails the barrier: the brake path is untested"


def test_the_bridge_drives_the_filters_certified_command_unchanged():
    """The LIMO bridge in Ackermann mode, given a command the filter certified (|ω| ≤ κ|v|, within
    the speed limits), drives that same (v, ω): no second clamp changes the path."""
    limits = LimoLimits()
    for v in np.linspace(-0.8, 0.8, 17):
        for frac in np.linspace(-1.0, 1.0, 9):
            w = float(v * frac * KAPPA)
            if abs(v) + abs(w) * limits.track / 2 > limits.max_wheel_speed or abs(w) > limits.max_angular:
                continue
            assert ackermann_velocity(float(v), w, limits) == pytest.approx((v, w), abs=1e-12)
            motion = command_to_motion(float(v), 0.0, w, MotionMode.ACKERMANN, limits)
            assert motion.linear == pytest.approx(v)
    assert limits.max_curvature == pytest.approx(KAPPA)  # one limit: the platform's


def test_steering_is_a_setting_of_a_wheeled_model_only():
    assert FilterConfig(steering="ackermann").steering_limit == (KAPPA, LIMO.min_steering_speed)
    assert FilterConfig().steering_limit is None
    with pytest.raises(ValueError, match="steering 'ackermann' is a wheeled robot's"):
        FilterConfig(model="double3d", steering="ackermann")
    with pytest.raises(ValueError, match="steering"):
        FilterConfig(steering="akerman")  # type: ignore[arg-type]
