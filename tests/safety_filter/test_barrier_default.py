"""The default double-integrator barrier is the braking barrier with the speed floor
a_b/k₂ (``BarrierParams.brake_speed_floor=None``): below that approach speed it is the paper's
HOCBF, so at equal margin it is no worse than the paper's filter, and above it the braking
parabola keeps the rows feasible within |aᵢ| ≤ a_max (``barriers.DoubleIntegrator``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.fields import FieldSample
from riskfield.services.safety_filter.barriers import Braking, DoubleIntegrator
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.state import FilterState

A_MAX = 1.5
GAINS = np.array([[1.5, 2.5, 1.5]])  # the safety benchmark's: k₁ = 1, k₂ = 1.5
K1, K2 = 1.0, 1.5
S1 = 0.7 * A_MAX / K2  # the speed floor a_b / k₂ = 0.7 m/s


def sample_at(hb: float, grad: np.ndarray, hess: np.ndarray) -> FieldSample:
    return FieldSample(np.array([hb + 0.15]), grad[None], hess[None], np.array([1]), np.array([True]))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_below_the_speed_floor_the_braking_row_is_the_papers_hocbf_row(seed: int) -> None:
    rng = np.random.default_rng(seed)
    g = rng.normal(size=3)
    g /= np.linalg.norm(g)
    m = rng.normal(size=(3, 3))
    hess = 3.0 * (m + m.T)
    v = rng.normal(0, 0.3, 3)
    s = -float(g @ v)
    if s >= S1:
        return
    hb = float(rng.uniform(0.0, 0.5))
    if s > K2 * hb:  # ψ₁ = ḣ + k₂ h < 0: outside both safe sets (their recoveries differ there)
        hb = s / K2 + 1e-3
    state, sample = FilterState(np.zeros(3), velocity=v), sample_at(hb, g, hess)
    braking = DoubleIntegrator(0.15, a_max=A_MAX, dt=0.05, barrier=Braking(speed_floor=None))
    hocbf = DoubleIntegrator(0.15, a_max=A_MAX, dt=0.05, barrier=Braking(kind="hocbf"))
    a, b = braking.rows(state, sample, np.array([hb]), GAINS, np.zeros(3))
    a_p, b_p = hocbf.rows(state, sample, np.array([hb]), GAINS, np.zeros(3))
    np.testing.assert_allclose(K2 * a, a_p, atol=1e-12)  # the same half-space, scaled by 1/k₂
    assert K2 * b[0] == pytest.approx(b_p[0], abs=1e-9)
    # And h_b = h + ḣ/k₂ = ψ₁/k₂.
    assert braking.barrier(state, sample, np.array([hb]), gains=GAINS)[0] == pytest.approx(
        min(hb, hb - s / K2), abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(s=st.floats(0.0, 3.0), hb=st.floats(0.0, 2.0))
def test_on_the_boundary_braking_along_the_gradient_satisfies_the_row(s: float, hb: float) -> None:
    """At h_b = 0, with a straight wall (no curvature), u = a_max ∇d satisfies the row at any
    approach speed, also above the floor, where the paper's HOCBF would ask more than a_max."""
    g = np.array([1.0, 0.0, 0.0])
    model = DoubleIntegrator(0.15, a_max=A_MAX, dt=0.05, barrier=Braking(speed_floor=None))
    state = FilterState(np.zeros(3), velocity=-s * g)
    phi = model.braking_distance(np.array(s), GAINS[0])[0]
    h = float(phi)  # h_b = 0
    a, b = model.rows(state, sample_at(h, g, np.zeros((3, 3))), np.array([h]), GAINS, np.zeros(3))
    assert a[0] @ (A_MAX * g) >= b[0] - 1e-9
    assert float(phi) >= s * s / (2 * model.a_brake) - 1e-12  # and h_b ≥ 0 still means it can stop


def test_a_robot_inside_an_obstacle_that_backs_out_is_not_in_the_safe_set() -> None:
    """φ(s) < 0 credits a receding robot, by s/k₂ with the floor a_b/k₂: h_b alone would call a
    robot 10 cm inside an obstacle safe; the safe set is {h ≥ 0, h_b ≥ 0}."""
    g = np.array([1.0, 0.0, 0.0])
    model = DoubleIntegrator(0.15, a_max=A_MAX, dt=0.05, barrier=Braking(speed_floor=None))
    state = FilterState(np.zeros(3), velocity=0.3 * g)  # moving away from the obstacle
    hb = np.array([-0.1])
    assert model.barrier(state, sample_at(-0.1, g, np.zeros((3, 3))), hb, gains=GAINS)[0] == pytest.approx(-0.1)


def test_the_default_takes_the_floor_from_the_gains() -> None:
    cfg = FilterConfig(model="double3d")
    assert cfg.barrier == "braking" and cfg.brake_speed_floor is None and math.isinf(cfg.brake_rate_length)
    model = cfg.build_model()
    g = np.array([1.0, 0.0, 0.0])
    state = FilterState(np.zeros(3), velocity=-0.2 * g)
    with pytest.raises(ValueError, match="gains"):
        model.barrier(state, sample_at(0.3, g, np.zeros((3, 3))), np.array([0.3]))
    # The high group (α₁ = 1.2, α₂ = 0.36: k₂ = 0.6) budgets a longer distance than the low one.
    high, low = np.array([0.6, 1.2, 0.36]), np.array([1.5, 2.5, 1.5])
    assert model.braking_distance(np.array(0.2), high)[0] > model.braking_distance(np.array(0.2), low)[0]
    assert model.braking_distance(np.array(0.2), low)[0] == pytest.approx(0.2 / K2)
