"""The filter under a map of uncertain scale: the field shrunk by the alignment's σ and residual, the
speed capped until the estimate converges, and the status saying so."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import Alignment, RobotState, VelocityCommand, encode
from riskfield.services.fields import AnalyticField, EsdfField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Plane
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.scale_guard import ScaleGuard, ScaleGuardConfig, ShrunkField, shrink
from riskfield.services.safety_filter.supervisor import FilterSupervisor

GROUPS = ["high", "mid", "low"]


def wall(x: float = 2.0) -> AnalyticField:
    return AnalyticField(Plane.through([x, 0.0, 0.0], [-1.0, 0.0, 0.0], label=3), groups=GROUPS)


def alignment(sigma: float, residual: float = 0.0, converged: bool | None = None) -> Alignment:
    return Alignment(scale=1.0, rotation=(0.0, 0.0, 0.0, 1.0), translation=(0.0, 0.0, 0.0), scale_sigma=sigma,
                     residual=residual, converged=sigma < 0.01 if converged is None else converged)


def state() -> RobotState:
    return RobotState(position=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0),
                      linear_velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0))


def ref(v: float = 0.5, w: float = 0.2) -> VelocityCommand:
    return VelocityCommand(linear=(v, 0.0, 0.0), angular=(0.0, 0.0, w), source="joy")


def make() -> FilterSupervisor:
    return FilterSupervisor(SafetyFilter(FilterConfig()), 0.3, 0.3, 0.2, scale_guard=ScaleGuardConfig())


def test_without_an_alignment_nothing_changes() -> None:
    sup = make()
    sup.on_map(wall(3.0), 0.0)
    sup.on_state(state(), 0.0)
    sup.on_ref(ref(), 0.0)
    cmd, status = sup.tick(0.01)
    assert status.fallback is None and not status.scale_uncertain and status.speed_cap is None
    assert status.distance_margin == 0.0 and cmd.linear[0] == pytest.approx(0.5, abs=1e-6)
    assert sup.guard.field(sup._slots["map"].value) is sup._slots["map"].value  # type: ignore[arg-type]


def test_uncertain_scale_caps_the_speed_keeps_the_curvature_and_says_so() -> None:
    sup = make()
    sup.on_map(wall(3.0), 0.0)
    sup.on_state(state(), 0.0)
    sup.on_ref(ref(0.5, 0.2), 0.0)
    sup.on_alignment(alignment(0.05, 0.004), 0.0)
    cmd, status = sup.tick(0.01)
    assert status.fallback is None and status.scale_uncertain and status.speed_cap == 0.2
    assert cmd.linear[0] == pytest.approx(0.2, abs=1e-6)
    assert cmd.angular[2] / cmd.linear[0] == pytest.approx(0.2 / 0.5, rel=1e-3)  # the curvature stays
    # d' = d − 2·(0.05·d + 0.004): at the critical point, ~3 m minus the look-ahead and body
    assert status.distance_margin > 0.2 and status.h < 2.6
    assert sup.counts["scale_uncertain"] == 1
    encode(status)
    # converged: no cap, a small margin
    sup.on_alignment(alignment(0.004, 0.002), 0.02)
    cmd, status = sup.tick(0.03)
    assert not status.scale_uncertain and status.speed_cap is None and cmd.linear[0] == pytest.approx(0.5, abs=1e-6)
    assert 0.0 < status.distance_margin < 0.04
    # an alignment that stops coming is not trusted as converged
    sup.on_ref(ref(0.5, 0.2), 2.0)
    sup.on_map(wall(3.0), 2.0)
    sup.on_state(state(), 2.0)
    _, status = sup.tick(2.01)
    assert status.scale_uncertain and status.speed_cap == 0.2


def test_uncertainty_brings_the_stop_closer_to_the_robot() -> None:
    # The robot 0.5 m from a wall: the shrunk field makes the barrier bind harder.
    sup = make()
    sup.on_map(wall(0.6), 0.0)
    sup.on_state(state(), 0.0)
    sup.on_ref(ref(0.2, 0.0), 0.0)
    free, _ = sup.tick(0.01)
    sup.on_alignment(alignment(0.08, 0.01), 0.01)
    guarded, status = sup.tick(0.02)
    assert guarded.linear[0] < free.linear[0] and status.h < 0.3


@settings(max_examples=40, deadline=None)
@given(sigma=st.floats(0.0, 0.2), residual=st.floats(0.0, 0.05), x=st.floats(-0.5, 6.0))
def test_the_grid_and_the_analytic_field_shrink_alike(sigma: float, residual: float, x: float) -> None:
    g = ScaleGuard(ScaleGuardConfig(k_sigma=2.0, max_range=4.0))
    g.on_alignment(alignment(sigma, residual), 0.0)
    a, b = g.params()
    assert a >= 2 * min(sigma, 1.0) - 1e-12 or a == 0.95  # rounded up, never down
    assert b >= 2 * residual - 1e-12
    field = wall(3.0)
    p = np.array([[3.0 - x, 0.0, 0.0]])
    d = field.query(p).distance
    out = ShrunkField(field, a, b, 4.0).query(p)
    assert out.distance == pytest.approx(shrink(d, a, b, 4.0))
    assert float(out.distance[0]) <= float(d[0]) - b + 1e-12
    grid = EsdfField.from_grid(to_grid_message(to_esdf(field, [-1, -1, 0], [3, 1, 0], 0.05, planar=True)),
                               "trilinear")
    shrunk = g.field(grid)
    assert isinstance(shrunk, EsdfField) and g.field(grid) is shrunk  # built once per map and estimate
    np.testing.assert_allclose(shrunk.distance, shrink(grid.distance, a, b, 4.0), atol=1e-6)


def test_margin_at_inverts_the_shrink() -> None:
    g = ScaleGuard()
    assert g.margin_at(1.0) == 0.0
    g.on_alignment(alignment(0.05, 0.01), 0.0)
    a, b = g.params()
    for d in (0.0, 0.5, 2.0, 3.9, 6.0):
        shrunk = float(shrink(np.array([d]), a, b, 4.0)[0])
        assert g.margin_at(shrunk) == pytest.approx(d - shrunk, abs=1e-9)
    assert not math.isnan(g.margin_at(-1.0))
