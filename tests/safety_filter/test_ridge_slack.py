"""The safety benchmark's relaxed steps and map-resolution collisions, as regressions.

* At the ridge of the distance field (where the nearest obstacle changes) the braking barrier's
  row needs ḣ_b ≈ -s (1 + |vᵀ∇²d v| / a_b); with the linear class-K function κ h_b that is
  infeasible far from any obstacle. The numbers are those of a relaxed step of the benchmark.
* The ESDF places a face no ray hit only to within a voxel: the filter keeps half a voxel more.
* The slack QP's backup: braking along the critical point's gradient at a ridge drives into the
  other obstacle; the filter takes the candidate whose worst row does best.
* Crossing the ridge between two obstacles at speed, the predictive row (the other obstacle's
  gradient, the ridge's curvature ahead) asks more than the box holds while the current rows are
  easily met: the predictive rows are soft, the step is not a relaxed one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from oracles.filter_step import ReferenceFilter
from riskfield.protocol import RiskConfig
from riskfield.services.fields import AnalyticField, FieldSample
from riskfield.services.fields.analytic import to_esdf
from riskfield.services.geometry.shapes import Sphere
from riskfield.services.safety_filter.barriers import Braking, DoubleIntegrator
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.state import FilterState

A_MAX = 1.5
GAINS = np.array([[1.5, 2.5, 1.5]])  # the benchmark's uniform gains: κ = 1


def ridge_state(hb: float) -> tuple[FilterState, FieldSample]:
    """|∇d| = 0.43, approach speed 0.152 m/s, vᵀ∇²d v = -2.53 m/s² (benchmark, procedural_0)."""
    g = np.array([[0.43, 0.0, 0.0]])
    v = np.array([-0.152 / 0.43, 0.3, 0.0])
    hess = (-2.53 / float(v @ v)) * np.eye(3)[None]
    sample = FieldSample(np.array([hb + 0.15]), g, hess, np.array([1]), np.array([True]))
    return FilterState(np.zeros(3), velocity=v), sample


@pytest.mark.parametrize(("ell", "feasible"), [(math.inf, False), (0.02, True)])
def test_braking_row_at_a_ridge_far_from_the_obstacle(ell: float, feasible: bool) -> None:
    s, sample = ridge_state(0.155)
    # On the parabola (a floor below the 0.152 m/s approach), where the ridge's curvature bites.
    m = DoubleIntegrator(0.15, a_max=A_MAX, dt=0.05, barrier=Braking(rate_length=ell, speed_floor=1e-3))
    a, b = m.rows(s, sample, np.array([0.155]), GAINS, np.zeros(3))
    assert (b[0] <= A_MAX * np.abs(a[0]).sum()) == feasible


def test_the_class_k_function_is_the_linear_one_at_the_boundary() -> None:
    s, sample = ridge_state(1e-4)
    lin = DoubleIntegrator(0.15, a_max=A_MAX, dt=0.05, barrier=Braking(rate_length=math.inf))
    new = DoubleIntegrator(0.15, a_max=A_MAX, dt=0.05)
    hb = np.array([1e-4])
    assert new.rows(s, sample, hb, GAINS, np.zeros(3))[1] == pytest.approx(
        lin.rows(s, sample, hb, GAINS, np.zeros(3))[1], abs=1e-6)
    # The default is the linear κ h_b: a steeper rate far out brings the robot within
    # millimetres of the map's surface, where any error of the map is a collision.
    assert FilterConfig(model="double3d").build_model().rate_length == math.inf
    with pytest.raises(ValueError):
        DoubleIntegrator(0.15, barrier=Braking(rate_length=0.0))


def test_gridded_fields_keep_half_a_voxel_more() -> None:
    exact = AnalyticField(Sphere([0.0, 0.0, 0.0], 0.3))
    esdf = to_esdf(exact, [-1.0, -1.0, -0.5], [1.0, 1.0, 0.5], 0.05)
    f = SafetyFilter(FilterConfig(model="double3d", robot_radius=0.15, a_max=A_MAX, rate_hz=20), RiskConfig())
    s = FilterState(np.array([-0.7, 0.0, 0.0]), velocity=np.array([0.3, 0.0, 0.0]))
    on_exact, on_grid = f.filter(s, np.zeros(3), exact), f.filter(s, np.zeros(3), esdf)
    assert on_exact.margin == pytest.approx(on_exact.h - f.delta, abs=1e-9)
    assert on_grid.margin == pytest.approx(on_grid.h - f.delta - 0.025, abs=1e-9)


def test_slack_backup_at_a_ridge_does_not_drive_into_the_other_obstacle() -> None:
    f = SafetyFilter(FilterConfig(model="double3d", robot_radius=0.15, a_max=A_MAX, rate_hz=20), RiskConfig())
    # Between two walls (gradients +x and -x), moving towards the +x wall: maximal braking along
    # +x (away from the -x wall, the critical point's) would give up the other wall's row.
    s = FilterState(np.zeros(3), velocity=np.array([0.2, 0.0, 0.0]))
    grads = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    a = grads * 0.2
    b = np.array([0.2, 0.25])  # u_x ≥ 1 and u_x ≤ -1.25: each alone feasible, not both
    u = ReferenceFilter(f)._backup(s, a, b, grads)  # the step's choice of backup, as its oracle makes it
    worst = lambda u_: float(((a @ u_ - b) / np.linalg.norm(a, axis=1)).min())  # noqa: E731
    assert worst(u) >= worst(f.model.backup(s, grads[0])) and worst(u) >= worst(f.model.backup(s, grads[1]))
    assert u[0] < 0  # it brakes the approach to the +x wall


@pytest.mark.parametrize(("floor", "fallback"), [(1e-3, "slack"), (0.1, None)])
def test_at_rest_just_inside_the_barrier_the_qp_stays_feasible(floor: float, fallback: str | None) -> None:
    """A robot stopped 5 mm inside its barrier (a sampled-data overshoot where it came to rest):
    with the braking barrier's coefficient s/a_b alone no input raises h_b at once."""
    exact = AnalyticField(Sphere([0.0, 0.0, 0.0], 0.3))
    fc = FilterConfig(model="double3d", robot_radius=0.15, a_max=A_MAX, v_max=0.5, rate_hz=20,
                      brake_speed_floor=floor)
    f = SafetyFilter(fc, RiskConfig())
    s = FilterState(np.array([-(0.3 + 0.15 + f.delta - 0.005), 0.0, 0.0]), velocity=np.zeros(3))
    res = f.filter(s, np.array([1.0, 0.0, 0.0]), exact)  # the reference pushes on towards the ball
    assert res.fallback == fallback
    assert res.u[0] < 0  # either way it backs out


def test_braking_distance_is_c1_and_covers_the_stopping_distance() -> None:
    m = DoubleIntegrator(0.15, a_max=A_MAX, barrier=Braking(speed_floor=0.1))
    s = np.linspace(-0.5, 1.0, 3001)
    phi, dphi = m.braking_distance(s)
    assert np.all(phi[s >= 0] >= s[s >= 0] ** 2 / (2 * m.a_brake) - 1e-12)
    assert np.allclose(np.gradient(phi, s), dphi, atol=1e-3)
    assert phi[np.argmin(np.abs(s))] == pytest.approx(0.0, abs=1e-3)


@pytest.mark.parametrize("backend", ["step", "oracle"])
def test_crossing_a_ridge_the_predictive_rows_are_soft(backend: str) -> None:
    """Between two balls, 1.4 cm on the -x ball's side of the ridge and heading across it at
    0.18 m/s: the nearest obstacle changes within the period (the geometry of a relaxed step of
    the benchmark). The QP with every row hard is infeasible; with the predictive rows
    soft the current rows hold exactly and the step is no fallback."""
    risk = RiskConfig()
    risk = risk.model_copy(update={"groups": [g.model_copy(update={"alpha1": 2.5, "alpha2": 1.5})
                                              for g in risk.groups]})
    field = to_esdf(AnalyticField([Sphere((-0.45, 0.0, 0.0), 0.25), Sphere((0.45, 0.0, 0.0), 0.25)]),
                    [-1.0, -1.0, -0.5], [1.0, 1.0, 0.5], 0.05)

    def make(slack: bool) -> SafetyFilter | ReferenceFilter:
        # The braking barrier of the benchmark step (s₀ = 0.1 m/s, ℓ = 2 cm): under the default,
        # whose speed floor a_b/k₂ makes it the paper's HOCBF at low speed, this state approaches
        # too fast for its clearance and is outside the safe set.
        filt = SafetyFilter(FilterConfig(model="double3d", robot_radius=0.15, a_max=A_MAX, v_max=0.5, rate_hz=20,
                                         slack=slack, brake_speed_floor=0.1, brake_rate_length=0.02), risk)
        return filt if backend == "step" else ReferenceFilter(filt)

    s = FilterState(np.array([-0.014, -0.245, 0.0]), velocity=np.array([0.176, 0.414, 0.0]))
    u_ref = 2.0 * (np.array([0.0, 0.5, 0.0]) - s.velocity)
    assert make(False).filter(s, u_ref, field).fallback == "infeasible"  # every row hard
    f = make(True)
    res = f.filter(s, u_ref, field)
    assert res.fallback is None and res.intervening
    # The current rows (the barrier's CBF condition) hold at the filtered input.
    ff = f.field_for(field)
    sample = ff.query(f.model.points(s), hessian=True)
    hb = sample.distance - f.model.radius - f.delta - f.config.map_margin_voxels * field.voxel_size
    gains = f.gains.for_groups(ff.groups)[sample.risk_group]
    a, b = f.model.rows(s, sample, hb, gains, np.zeros(3))
    assert np.all(a @ res.u >= b - 1e-7)
    assert f.model.barrier(s, sample, hb, gains=gains).min() > 0  # inside the safe set: nothing to relax
