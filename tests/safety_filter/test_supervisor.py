"""Fail-safe supervision with explicit clocks, and the risk file loader/watcher."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskfield.protocol import RiskConfig, RiskGroup, RobotState, VelocityCommand, encode
from riskfield.services.fields import AnalyticField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Plane, Sphere
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.supervisor import FilterSupervisor

GROUPS = ["high", "mid", "low"]


def grid():
    return to_grid_message(to_esdf(AnalyticField(Sphere([1.0, 0.0, 0.0], 0.3, planar=True, label=1), groups=GROUPS),
                                   [-1, -1, 0], [2, 1, 0], 0.05, planar=True))


def state(x=0.0, y=0.0, yaw=0.0) -> RobotState:
    return RobotState(position=(x, y, 0.0), orientation=(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
                      linear_velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0))


def ref(v=0.5, w=0.0, source="joy") -> VelocityCommand:
    return VelocityCommand(linear=(v, 0.0, 0.0), angular=(0.0, 0.0, w), source=source)


def make(model: str = "unicycle") -> FilterSupervisor:
    return FilterSupervisor(SafetyFilter(FilterConfig(model=model)), 0.3, 0.3, 0.2)


def test_fallbacks_in_order_then_filtering():
    sup = make()
    cmd, st = sup.tick(0.0)
    assert st.fallback == "no_map" and st.h == 0.0 and st.esdf_age_ms == -1.0 and cmd.linear == (0, 0, 0)
    sup.on_map(grid(), 0.0)
    assert sup.tick(0.01)[1].fallback == "no_state"
    sup.on_state(state(), 0.01)
    _, st = sup.tick(0.02)
    assert st.fallback == "no_ref"
    assert st.h > 0 and st.risk_group == 1  # the clearance is reported even while braking
    sup.on_ref(ref(), 0.02)
    cmd, st = sup.tick(0.03)
    assert st.fallback is None and cmd.linear[0] > 0 and cmd.source == "safety-filter/joy"
    assert st.esdf_age_ms == pytest.approx(30.0)
    encode(cmd), encode(st)  # publishable: finite, valid


@pytest.mark.parametrize(("what", "age", "reason"), [
    ("map", 0.31, "stale_map"), ("state", 0.31, "stale_state"), ("ref", 0.21, "stale_ref")])
def test_each_input_times_out(what, age, reason):
    sup = make()
    t = 10.0
    sup.on_map(grid(), t)
    sup.on_state(state(), t)
    sup.on_ref(ref(), t)
    fresh = {"map": lambda: sup.on_map(grid(), t + age), "state": lambda: sup.on_state(state(), t + age),
             "ref": lambda: sup.on_ref(ref(), t + age)}
    for other, renew in fresh.items():
        if other != what:
            renew()
    assert sup.tick(t + age - 0.02)[1].fallback is None
    cmd, st = sup.tick(t + age)
    assert st.fallback == reason and cmd.linear == (0.0, 0.0, 0.0) and cmd.angular == (0.0, 0.0, 0.0)


def test_invalid_input_brakes_until_a_valid_one_arrives():
    sup = make()
    sup.on_map(grid(), 0.0)
    sup.on_state(state(), 0.0)
    sup.on_ref(ref(), 0.0)
    for what in ("ref", "state", "map"):
        sup.invalid(what, 0.01)
        assert sup.tick(0.01)[1].fallback == f"invalid_{what}"
        {"ref": lambda: sup.on_ref(ref(), 0.02), "state": lambda: sup.on_state(state(), 0.02),
         "map": lambda: sup.on_map(grid(), 0.02)}[what]()
        assert sup.tick(0.02)[1].fallback is None


def test_an_unusable_map_is_invalid():
    sup = make()
    g = grid()
    thin = g.model_copy(update={"distance": np.zeros((1, 5, 1), np.float32), "risk_group": np.zeros((1, 5, 1),
                                                                                                      np.uint8)})
    assert sup.on_map(thin, 0.0) is not None
    assert sup.tick(0.0)[1].fallback == "invalid_map"


def test_outside_map_and_the_double_integrator_through_the_supervisor():
    sup = make()
    sup.on_map(grid(), 0.0)
    sup.on_state(state(x=1.9), 0.0)
    sup.on_ref(ref(), 0.0)
    cmd, st = sup.tick(0.0)
    assert st.fallback == "outside_map" and cmd.linear == (0.0, 0.0, 0.0) and st.h == 0.0
    dbl = make("double3d")
    wall = AnalyticField(Plane.through([3, 0, 0], [-1, 0, 0], label=3), groups=GROUPS)
    dbl.on_map(to_grid_message(to_esdf(wall, [-1, -1, -1], [2, 1, 1], 0.1)), 0.0)
    moving = state().model_copy(update={"linear_velocity": (0.4, 0.0, 0.0)})
    dbl.on_state(moving, 0.0)
    dbl.on_ref(ref(1.0), 0.0)
    cmd, st = dbl.tick(0.0)
    # Desired 1 m/s from 0.4 m/s: u = k_v (1 - 0.4) = 1.2 m/s², command v + u T.
    assert st.fallback is None and cmd.linear[0] == pytest.approx(0.4 + 1.2 * 0.02)


def test_status_reports_the_intervention_and_a_braking_status_is_always_finite():
    sup = make()
    sup.on_map(grid(), 0.0)
    sup.on_state(state(x=0.3), 0.0)
    sup.on_ref(ref(1.0), 0.0)
    cmd, st = sup.tick(0.0)
    assert st.intervening and st.fallback is None and cmd.linear[0] < 1.0
    assert st.solve_us > 0 and sup.counts["ok"] == 1


# -- risk file ----------------------------------------------------------------------------------

def test_supervisor_hot_swaps_risk():
    sup = make()
    sup.on_map(grid(), 0.0)
    sup.on_state(state(x=0.2), 0.0)
    sup.on_ref(ref(1.0), 0.0)
    before = sup.tick(0.0)[0].linear[0]
    sup.set_risk(RiskConfig(groups=[RiskGroup(name="high", alpha=5.0)], default_group="high"))
    after = sup.tick(0.0)[0].linear[0]
    assert after > before + 0.05


def test_an_infeasible_step_publishes_the_slack_command_and_says_so():
    """Facing into a wall from inside the margin: the command backs out as asked (not zero), and
    the status names the step ``slack``."""
    sup = FilterSupervisor(SafetyFilter(FilterConfig(v_max=0.2)), 0.3, 0.3, 0.2)
    sup.on_map(AnalyticField(Plane.through([0.2, 0, 0], [-1.0, 0, 0], label=3), groups=GROUPS), 0.0)
    sup.on_state(state(x=0.1), 0.0)
    sup.on_ref(ref(v=-0.15), 0.0)
    cmd, st = sup.tick(0.01)
    assert st.fallback == "slack" and st.intervening and st.h < 0
    assert cmd.linear[0] == pytest.approx(-0.15)
    assert sup.counts["slack"] == 1
    sup.on_ref(ref(v=0.15), 0.0)
    cmd, st = sup.tick(0.02)
    assert st.fallback == "slack" and cmd.linear[0] == pytest.approx(0.0, abs=1e-9)  # no deeper
