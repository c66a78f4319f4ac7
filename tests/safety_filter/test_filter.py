"""The filter core: semantics (risk groups), fallbacks, solver paths."""

from __future__ import annotations

import math

import numpy as np
import pytest

from oracles.filter_step import ReferenceFilter
from riskfield.protocol import RiskConfig, RiskGroup
from riskfield.services.fields import AnalyticField, to_esdf
from riskfield.services.geometry.shapes import Plane, Sphere
from riskfield.services.safety_filter.config import FilterConfig, Footprint
from riskfield.services.safety_filter.filter import GainTable, SafetyFilter, hocbf_gains
from riskfield.services.safety_filter.model import YIELD
from riskfield.services.safety_filter.state import FilterState

GROUPS = ["high", "mid", "low"]


def first_intervention(field, model: str = "unicycle", v: float = 0.6) -> float:
    """Drive straight at an obstacle at +x; the clearance h when the filter first intervenes."""
    filt = SafetyFilter(FilterConfig(model=model))
    s = FilterState.planar(-1.5, 0.0, 0.0)
    u_ref = np.array([v, 0.0]) if filt.model.n == 2 else np.array([v, 0.0, 0.0])[: filt.model.n]
    for _ in range(400):
        res = filt.filter(s, u_ref, field)
        assert res.fallback is None
        if res.intervening:
            return res.h
        s = filt.model.integrate(s, res.u, filt.config.dt)
    raise AssertionError("never intervened")


@pytest.mark.parametrize("model", ["unicycle", "single2d"])
def test_higher_risk_intervenes_earlier_at_the_same_geometry(model):
    # Identical geometry and distance field; only the risk group of the obstacle differs.
    high = AnalyticField(Sphere([1.0, 0.0, 0.0], 0.3, planar=True, label=1), groups=GROUPS)
    low = AnalyticField(Sphere([1.0, 0.0, 0.0], 0.3, planar=True, label=3), groups=GROUPS)
    h_high, h_low = first_intervention(high, model), first_intervention(low, model)
    assert h_high > h_low + 0.2, (h_high, h_low)
    # The same on real grids built from each.
    g_high = to_esdf(high, [-2, -1, 0], [2, 1, 0], 0.05, planar=True)
    g_low = to_esdf(low, [-2, -1, 0], [2, 1, 0], 0.05, planar=True)
    assert first_intervention(g_high, model) > first_intervention(g_low, model) + 0.2


def test_intervention_starts_where_the_cbf_predicts():
    # Straight approach of the look-ahead point: ∇d·ṗ = -v, so the row binds when v > α (h - δ).
    field = AnalyticField(Plane.through([1.0, 0, 0], [-1.0, 0, 0], label=3), groups=GROUPS)
    filt = SafetyFilter(FilterConfig())
    alpha = RiskConfig().groups[2].alpha
    h = first_intervention(field, v=0.6)
    assert h - filt.delta == pytest.approx(0.6 / alpha, abs=0.6 * filt.config.dt + 1e-3)


def test_hocbf_higher_risk_brakes_earlier_and_keeps_more_clearance():
    def run(group: int) -> tuple[float, float]:
        field = AnalyticField(Sphere([1.5, 0, 0], 0.3, label=group), groups=GROUPS)
        filt = SafetyFilter(FilterConfig(model="double3d"))
        s = FilterState(np.zeros(3), np.eye(3), np.array([0.5, 0.0, 0.0]))
        first, hmin = None, math.inf
        for _ in range(500):
            u_ref = 2.0 * (np.array([0.5, 0.0, 0.0]) - s.velocity)
            res = filt.filter(s, u_ref, field)
            assert res.fallback is None
            if res.intervening and first is None:
                first = res.h
            s = filt.model.integrate(s, res.u, filt.config.dt)
            hmin = min(hmin, float(filt.model.h(s, field).min()))
        return first, hmin
    (f_high, min_high), (f_low, min_low) = run(1), run(3)
    assert f_high > f_low and min_high >= 0 and min_low >= 0


def test_gain_table_maps_groups_by_name_and_is_conservative_for_unknowns():
    risk = RiskConfig(groups=[RiskGroup(name="pet", alpha=0.5, alpha1=1.0, alpha2=0.2, margin=0.2),
                              RiskGroup(name="box", alpha=2.0, alpha1=3.0, alpha2=2.0)], default_group="box")
    table = GainTable(risk).for_groups(["box", "alien", "pet"])
    np.testing.assert_allclose(table[1], [2.0, 3.0, 2.0, 0.0, 0.0])
    np.testing.assert_allclose(table[3], [0.5, 1.0, 0.2, 0.2, 0.0])
    np.testing.assert_allclose(table[2], table[0])  # unknown name = id 0 = most conservative
    np.testing.assert_allclose(table[0], [0.5, 1.0, 0.2, 0.2, 0.0])


def test_groups_holding_a_yield_label_yield_and_unknown_obstacles_do_not():
    risk = RiskConfig()  # high = person, animal
    table = GainTable(risk, ["person"]).for_groups(["high", "mid", "low", "alien"])
    assert table[:, YIELD].tolist() == [0.0, 1.0, 0.0, 0.0, 0.0]
    assert not GainTable(risk).for_groups(["high"])[:, YIELD].any()  # no yield labels: the static barrier


def test_hocbf_gains_with_complex_roots_are_critically_damped():
    assert hocbf_gains(1.2, 0.4) == (1.2, pytest.approx(0.36))  # the default high group
    assert hocbf_gains(2.5, 1.5) == (2.5, 1.5)


def test_risk_hot_swap_changes_the_gains_used():
    field = AnalyticField(Plane.through([1.0, 0, 0], [-1.0, 0, 0], label=1), groups=["high"])
    filt = SafetyFilter(FilterConfig())
    s = FilterState.planar(0.0, 0.0, 0.0)
    before = filt.filter(s, np.array([1.0, 0.0]), field).u[0]
    filt.set_risk(RiskConfig(groups=[RiskGroup(name="high", alpha=3.0)], default_group="high"))
    after = filt.filter(s, np.array([1.0, 0.0]), field).u[0]
    assert after > before + 0.1


def test_margins_in_filter_apply_the_groups_margin():
    field = AnalyticField(Plane.through([1.0, 0, 0], [-1.0, 0, 0], label=1), groups=GROUPS)  # high: margin 0.15
    s = FilterState.planar(0.0, 0.0, 0.0)
    plain = SafetyFilter(FilterConfig()).filter(s, np.array([1.0, 0.0]), field)
    inflated = SafetyFilter(FilterConfig(margins_in_filter=True)).filter(s, np.array([1.0, 0.0]), field)
    assert inflated.u[0] == pytest.approx(plain.u[0] - 0.6 * 0.15, abs=1e-6)


def test_outside_the_map_brakes():
    grid = to_esdf(AnalyticField(Sphere([0.5, 0, 0], 0.2, planar=True)), [-1, -1, 0], [1, 1, 0], 0.05, planar=True)
    filt = SafetyFilter(FilterConfig())
    res = filt.filter(FilterState.planar(0.9, 0.0, 0.0), np.array([0.5, 0.0]), grid)  # look-ahead at 1.15
    assert res.fallback == "outside_map" and not res.u.any() and res.intervening


def test_non_finite_reference_brakes():
    filt = SafetyFilter(FilterConfig())
    field = AnalyticField(Plane.through([1.0, 0, 0], [-1.0, 0, 0]))
    for bad in ([np.nan, 0.0], [0.0, np.inf], [1.0, 2.0, 3.0]):
        res = filt.filter(FilterState.planar(0, 0, 0), np.array(bad), field)
        assert res.fallback == "non_finite" and not res.u.any()
    res = filt.filter(FilterState.planar(0, 0, 0), np.zeros(2), field, angular=np.array([0, 0, np.nan]))
    assert res.fallback == "non_finite"


def test_infeasible_inside_an_obstacle_brakes_without_slack():
    # Deep inside the inflated set: h - δ ≈ -0.5 needs an escape speed the bounds do not allow.
    field = AnalyticField(Plane.through([1.0, 0, 0], [-1.0, 0, 0], label=3), groups=GROUPS)
    filt = SafetyFilter(FilterConfig(v_max=0.2, slack=False))
    res = filt.filter(FilterState.planar(1.0, 0.0, 0.0), np.array([0.1, 0.0]), field)
    assert res.fallback == "infeasible" and not res.u.any()
    assert res.h < 0


@pytest.mark.parametrize("v_ref", [0.1, -0.15])
def test_infeasible_qp_is_relaxed_to_the_backup_not_a_blind_brake(v_ref):
    """Facing into a wall from inside the margin: no input satisfies the rows. The relaxed QP lets
    no point go deeper (as the backup u = 0) and otherwise follows the reference: backing out."""
    field = AnalyticField(Plane.through([1.0, 0, 0], [-1.0, 0, 0], label=3), groups=GROUPS)
    filt = SafetyFilter(FilterConfig(v_max=0.2))
    s = FilterState.planar(1.0, 0.0, 0.0)
    res = filt.filter(s, np.array([v_ref, 0.0]), field)
    assert res.fallback == "slack" and res.intervening and res.h < 0
    assert res.u[0] == pytest.approx(min(v_ref, 0.0), abs=1e-9)  # forward refused, reversing kept
    after = filt.model.integrate(s, res.u, filt.config.dt)
    assert (filt.model.h(after, field) >= filt.model.h(s, field) - 1e-9).all()


def test_double_integrator_slack_is_at_least_as_good_as_braking_along_the_gradient():
    field = AnalyticField(Plane.through([1.0, 0, 0], [-1.0, 0, 0], label=3), groups=GROUPS)
    filt = SafetyFilter(FilterConfig(model="double3d", a_max=1.0))
    s = FilterState(np.array([0.7, 0.0, 0.0]), velocity=np.array([1.0, 0.3, 0.0]))  # cannot stop in 15 cm
    res = filt.filter(s, np.array([1.0, 0.0, 0.0]), field)
    assert res.fallback == "slack"
    assert res.u[0] == pytest.approx(-1.0, abs=1e-6)  # the full deceleration along the gradient
    assert abs(res.u[1]) < 1.0  # the tangential part stays free: not a blind "-v/dt" brake


def test_solver_failure_brakes():
    filt = SafetyFilter(FilterConfig())
    field = AnalyticField(Plane.through([0.5, 0, 0], [-1.0, 0, 0], label=3), groups=GROUPS)
    s, u_ref = FilterState.planar(0.0, 0.0, 0.3), np.array([1.0, 0.5])
    assert filt.filter(s, u_ref, field).fallback is None and filt.filter(s, u_ref, field).intervening
    filt._step._i("max_iter")[0] = 0  # an active-set QP that cannot take a step
    res = filt.filter(s, u_ref, field)
    assert (res.fallback, res.solver) == ("solver_failed", "active_set") and not res.u.any()


@pytest.mark.parametrize("model", ["unicycle", "single2d", "single3d", "double3d"])
def test_osqp_and_the_active_set_path_agree_in_the_loop(model):
    planar = model in ("unicycle", "single2d")
    field = AnalyticField(Sphere([1.0, 0.2, 0.0], 0.3, planar=planar, label=1), groups=GROUPS)
    fast = SafetyFilter(FilterConfig(model=model))
    slow = ReferenceFilter(fast, solver="osqp")
    rng = np.random.default_rng(3)
    agree = 0
    # The braking barrier is active only when stopping gets close: approach the ball faster.
    towards = np.array([0.6 if model == "double3d" else 0.0, 0.0, 0.0])
    for _ in range(150):
        s = FilterState.planar(*rng.uniform([-0.2, -0.5], [0.5, 0.7]), rng.uniform(-3, 3),
                               velocity=tuple(rng.normal(0, 0.3, 3) + towards))
        u_ref = rng.uniform(fast.model.lo, fast.model.hi) * 1.2
        a, b = fast.filter(s, u_ref, field), slow.filter(s, u_ref, field)
        assert a.fallback == b.fallback
        if a.fallback is None:
            np.testing.assert_allclose(a.u, b.u, atol=5e-4)
            agree += a.intervening
        assert a.solver == ("active_set" if a.fallback is None else a.solver)
    assert agree > 20


def test_extra_points_add_rows_and_protect_the_rear():
    # Reversing into a wall behind the robot: only a rear point sees it.
    wall = AnalyticField(Plane.through([-0.4, 0, 0], [1.0, 0, 0], label=3), groups=GROUPS)
    s = FilterState.planar(0.0, 0.0, 0.0)
    paper = FilterConfig(footprint=Footprint(shape="none"))
    front_only = SafetyFilter(paper).filter(s, np.array([-0.4, 0.0]), wall)
    rear = SafetyFilter(paper.model_copy(update={"extra_points": [(-0.2, 0.0, 0.0)]}))
    assert rear.model.m == 2
    with_rear = rear.filter(s, np.array([-0.4, 0.0]), wall)
    assert not front_only.intervening and front_only.u[0] == -0.4
    # rear point: h - δ = 0.2 - 0.15 - δ, so |v| ≤ α_low (h - δ)
    assert with_rear.intervening
    assert with_rear.u[0] == pytest.approx(-1.5 * (0.05 - rear.delta), abs=1e-6)


def test_filter_is_identity_far_from_obstacles():
    field = AnalyticField(Sphere([5.0, 5.0, 0.0], 0.3, planar=True, label=1), groups=GROUPS)
    filt = SafetyFilter(FilterConfig())
    res = filt.filter(FilterState.planar(0, 0, 0.3), np.array([0.7, -0.4]), field)
    assert res.fallback is None and not res.intervening
    np.testing.assert_array_equal(res.u, [0.7, -0.4])
    assert res.h == pytest.approx(math.hypot(5 - 0.25 * math.cos(0.3), 5 - 0.25 * math.sin(0.3)) - 0.3 - 0.15)


def test_the_limo_footprint_protects_the_rear_by_default():
    """The default unicycle carries the LIMO's disc cover: reversing towards a wall 0.4 m behind is
    limited by the rear disc (its edge 0.161 m behind the centre) with the low group's gain."""
    wall = AnalyticField(Plane.through([-0.4, 0, 0], [1.0, 0, 0], label=3), groups=GROUPS)
    filt = SafetyFilter(FilterConfig())
    assert filt.model.m == 4  # look-ahead point + 3 discs
    res = filt.filter(FilterState.planar(0.0, 0.0, 0.0), np.array([-0.8, 0.0]), wall)
    rear_x, r = filt.model.offsets[1, 0], filt.model.radius[1]
    assert rear_x == pytest.approx(-0.322 / 3) and r == pytest.approx(math.hypot(0.322 / 6, 0.11))
    assert res.intervening and res.u[0] == pytest.approx(-1.5 * (0.4 + rear_x - r - filt.delta), abs=1e-6)


def test_the_unicycle_is_the_limo_and_takes_its_limits_from_the_platform():
    """The LIMO's figures are written once (``protocol.platforms.LIMO``): the unicycle's body and
    bounds default to them, the point models keep the generic bounds, a set bound always wins."""
    from riskfield.protocol.platforms import LIMO
    from riskfield.services.safety_filter.config import BoundsParams

    limo = FilterConfig()
    assert (limo.v_max, limo.w_max, limo.a_max) == (LIMO.max_linear, LIMO.max_angular, LIMO.max_accel)
    assert (limo.body().length, limo.body().width) == (LIMO.length, LIMO.width)
    assert limo.build_model().spec.hi.tolist() == [LIMO.max_linear, LIMO.max_angular]
    generic = BoundsParams()
    assert FilterConfig(model="double3d").a_max == generic.a_max != LIMO.max_accel
    assert FilterConfig(a_max=2.5).a_max == 2.5 and FilterConfig(model="unicycle", w_max=1.0).a_max == LIMO.max_accel
    assert FilterConfig.compose(bounds=BoundsParams(v_max=0.5)).a_max == LIMO.max_accel
    assert FilterConfig.compose(bounds=BoundsParams(a_max=3.0)).a_max == 3.0


def test_footprints_build_their_disc_covers_and_bad_ones_are_clear_errors():
    from pydantic import ValidationError

    cap = SafetyFilter(FilterConfig(model="single2d", footprint=Footprint(shape="capsule", discs=4))).model
    assert cap.m == 4 and np.all(cap.radius == pytest.approx(math.hypot(0.102 / 3 / 2, 0.11)))
    ball = SafetyFilter(FilterConfig(model="double3d", footprint=Footprint(shape="sphere", radius=0.2))).model
    assert ball.m == 1 and ball.radius[0] == 0.2
    with pytest.raises(ValidationError, match="no heading"):
        FilterConfig(model="double3d", footprint=Footprint(shape="rectangle"))
    with pytest.raises(ValidationError):
        Footprint(shape="blob")  # type: ignore[arg-type]
