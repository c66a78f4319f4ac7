"""Barrier models: f, g, the CBF rows and the exact integrators agree with each other."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.fields import AnalyticField
from riskfield.services.geometry.shapes import Sphere
from riskfield.services.geometry.transforms import quat_to_matrix
from riskfield.services.safety_filter.barriers import Braking, DoubleIntegrator, SingleIntegrator, UnicycleLookahead
from riskfield.services.safety_filter.state import FilterState, so3_exp

FIELD = AnalyticField(Sphere([2.0, 0.5, 0.3], 0.6, label=1), groups=["high"])
FIELD_2D = AnalyticField(Sphere([2.0, 0.5, 0.0], 0.6, planar=True, label=1), groups=["high"])


def random_state(rng, model) -> FilterState:
    p = rng.uniform(-0.5, 0.5, 3)
    if isinstance(model, UnicycleLookahead) or (isinstance(model, SingleIntegrator) and model.dim == 2):
        return FilterState.planar(p[0], p[1], rng.uniform(-math.pi, math.pi), velocity=(0.2, 0.1, 0.0))
    return FilterState(p, so3_exp(rng.normal(0, 0.7, 3)), rng.normal(0, 0.5, 3))


MODELS = [
    UnicycleLookahead(0.3, 0.1, extra_points=[(-0.2, 0.1, 0.0)]),
    SingleIntegrator(2, 0.1, points=[(0.0, 0.0, 0.0), (0.3, -0.1, 0.0)]),
    SingleIntegrator(3, 0.1, points=[(0.0, 0.0, 0.0), (0.2, 0.1, -0.1)]),
    # A speed floor far below every speed drawn: the braking barrier is the parabola h - s₊²/(2 a_b).
    DoubleIntegrator(0.1, points=[(0.0, 0.0, 0.0), (0.1, 0.0, 0.0)], barrier=Braking(speed_floor=1e-3)),
]
IDS = ["unicycle", "single2d", "single3d", "double3d"]


@pytest.mark.parametrize("model", MODELS, ids=IDS)
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_point_jacobians_are_the_derivative_of_the_exact_motion(model, seed):
    """ṗ_i = J_i u + ω_pass × (R o_i) (order 1: the description's g and f), ṗ = v, v̇ = u (order 2),
    against central differences of the exact integrator."""
    rng = np.random.default_rng(seed)
    s = random_state(rng, model)
    u = rng.uniform(model.lo, model.hi)
    ang = rng.normal(0, 0.7, 3)
    eps = 1e-6
    fwd, bwd = model.integrate(s, u, eps, ang), model.integrate(s, u, -eps, ang)
    p_dot = (model.points(fwd) - model.points(bwd)) / (2 * eps)
    if isinstance(model, DoubleIntegrator):
        np.testing.assert_allclose(p_dot, np.broadcast_to(s.velocity, p_dot.shape), atol=1e-6)
        np.testing.assert_allclose((fwd.velocity - bwd.velocity) / (2 * eps), u, atol=1e-6)
        return
    r = model.rotation(s)
    spin = r @ (np.asarray(model.spec.passthrough) * ang)  # the passed-through rates, world frame
    expected = model.point_jacobians(s) @ u + np.cross(spin, model.offsets @ r.T)
    np.testing.assert_allclose(p_dot, expected, atol=1e-6)


@pytest.mark.parametrize("model", MODELS[:3], ids=IDS[:3])
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_first_order_rows_predict_the_barrier_rate(model, seed):
    rng = np.random.default_rng(seed)
    field = FIELD_2D if (model.lo.shape[0] == 2 and not isinstance(model, SingleIntegrator)) or (
        isinstance(model, SingleIntegrator) and model.dim == 2) else FIELD
    s = random_state(rng, model)
    u = rng.uniform(model.lo, model.hi)
    ang = rng.normal(0, 0.8, 3)
    if not (isinstance(model, SingleIntegrator) and model.dim == 3):
        ang[:2] = 0.0
    alpha = rng.uniform(0.3, 2.0, model.m)
    gains = np.stack([alpha, np.ones(model.m), np.ones(model.m)], axis=1)
    sample = field.query(model.points(s))
    h = model.h(s, field)
    a, b = model.rows(s, sample, h, gains, ang)
    assert a.shape == (model.m, model.n) and b.shape == (model.m,)
    # Row i is ḣ_i(u) ≥ -α_i h_i, i.e. ḣ_i = A_i u - (b_i + α_i h_i).
    predicted = a @ u - (b + alpha * h)
    eps = 1e-6
    integ_ang = ang if isinstance(model, SingleIntegrator) else None
    numeric = (model.h(model.integrate(s, u, eps, integ_ang), field)
               - model.h(model.integrate(s, u, -eps, integ_ang), field)) / (2 * eps)
    np.testing.assert_allclose(predicted, numeric, atol=1e-5)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_hocbf_row_uses_the_second_derivative_of_h(seed):
    model = DoubleIntegrator(0.1, points=[(0.0, 0.0, 0.0), (0.1, 0.0, 0.0)], barrier=Braking(kind="hocbf"))
    rng = np.random.default_rng(seed)
    s = random_state(rng, model)
    u = rng.uniform(model.lo, model.hi)
    sample = FIELD.query(model.points(s), hessian=True)
    h = model.h(s, FIELD)
    a1, a2 = 2.5, 1.5  # real roots 1, 1.5
    gains = np.array([[1.0, a1, a2]] * model.m)
    a, b = model.rows(s, sample, h, gains, np.zeros(3))
    eps = 1e-4
    hp, h0, hm = (model.h(model.integrate(s, u, t), FIELD) for t in (eps, 0.0, -eps))
    hdd = (hp - 2 * h0 + hm) / eps**2
    hd = (hp - hm) / (2 * eps)
    np.testing.assert_allclose(a @ u + np.einsum("i,mij,j->m", s.velocity, sample.hessian, s.velocity), hdd,
                               atol=1e-4)
    psi1 = hd + 1.5 * h
    ok = psi1 >= 0
    # Inside the HOCBF safe set the row is the paper's: ḧ + α₁ḣ + α₂h ≥ 0  ⇔  A u ≥ b.
    np.testing.assert_allclose((a @ u - b)[ok], (hdd + a1 * hd + a2 * h)[ok], atol=1e-4)
    # Outside it the row is stricter (a larger recovery gain), never weaker.
    assert np.all((a @ u - b)[~ok] <= (hdd + a1 * hd + a2 * h)[~ok] + 1e-4)


def test_unicycle_lookahead_jacobian_is_the_papers():
    model = UnicycleLookahead(0.4)
    th = 0.7
    s = FilterState.planar(1.0, 2.0, th)
    j = model.point_jacobians(s)[0]
    np.testing.assert_allclose(j[2], 0.0)
    np.testing.assert_allclose(j[:2], [[math.cos(th), -0.4 * math.sin(th)], [math.sin(th), 0.4 * math.cos(th)]])
    np.testing.assert_allclose(model.points(s)[0], [1.0 + 0.4 * math.cos(th), 2.0 + 0.4 * math.sin(th), 0.0])


@pytest.mark.parametrize("model", MODELS, ids=IDS)
def test_max_point_speed_bounds_every_admissible_input(model):
    rng = np.random.default_rng(5)
    bound = model.max_point_speed()
    for _ in range(200):
        s = random_state(rng, model)
        if isinstance(model, DoubleIntegrator):
            continue  # velocity is a state there; its bound is the nominal v_max
        u = rng.uniform(model.lo, model.hi)
        ang = np.array([0.0, 0.0, rng.uniform(-2, 2)]) if not isinstance(model, UnicycleLookahead) else None
        if isinstance(model, SingleIntegrator) and model.dim == 3:
            ang = rng.normal(0, 1, 3)
            ang *= min(1.0, 2.0 / np.linalg.norm(ang))
        eps = 1e-6
        speed = np.linalg.norm(model.points(model.integrate(s, u, eps, ang)) - model.points(s), axis=1) / eps
        assert speed.max() <= bound + 1e-4


def test_body_frame_conversions():
    yaw = 0.5
    s = FilterState.planar(0, 0, yaw, velocity=(0.3, 0.1, 0.0))
    uni = UnicycleLookahead()
    np.testing.assert_allclose(uni.reference(np.array([0.4, 9.0, 9.0]), np.array([9.0, 9.0, 0.3]), s), [0.4, 0.3])
    lin, ang = uni.command(np.array([0.2, -0.1]), np.zeros(3), s)
    np.testing.assert_allclose(lin, [0.2, 0, 0])
    np.testing.assert_allclose(ang, [0, 0, -0.1])
    single = SingleIntegrator(2)
    lin, ang = single.command(np.array([0.2, 0.1]), np.array([1.0, 1.0, 0.4]), s)
    np.testing.assert_allclose(lin, [0.2, 0.1, 0]) and np.testing.assert_allclose(ang, [0, 0, 0.4])
    # The double integrator tracks a body-frame desired velocity and commands v + u T (body frame).
    dbl = DoubleIntegrator(k_v=2.0, dt=0.02)
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    s3 = FilterState(np.zeros(3), quat_to_matrix(q), np.array([0.3, 0.1, 0.0]))
    u = dbl.reference(np.array([1.0, 0.0, 0.0]), np.zeros(3), s3)
    np.testing.assert_allclose(u, 2.0 * (np.array([math.cos(yaw), math.sin(yaw), 0.0]) - s3.velocity))
    lin, _ = dbl.command(u, np.zeros(3), s3)
    np.testing.assert_allclose(s3.rotation @ lin, s3.velocity + 0.02 * u)
    np.testing.assert_allclose(dbl.brake(s3), [-3.0, -1.0, 0.0])  # against v, scaled into |a_i| ≤ 3
    slow = FilterState(np.zeros(3), np.eye(3), np.array([0.01, -0.02, 0.0]))
    np.testing.assert_allclose(dbl.brake(slow), [-0.5, 1.0, 0.0])  # stops within one period


def test_bounds_must_allow_braking():
    with pytest.raises(ValueError):
        UnicycleLookahead(v_max=-1.0)


@pytest.mark.parametrize("model", MODELS, ids=IDS)
def test_predicted_points_are_the_points_after_the_exact_step(model):
    rng = np.random.default_rng(9)
    for _ in range(20):
        s = random_state(rng, model)
        u = rng.uniform(model.lo, model.hi)
        ang = np.array([0.0, 0.0, rng.uniform(-2, 2)])
        np.testing.assert_allclose(model.predicted_points(s, u, 0.02, ang),
                                   model.points(model.integrate(s, u, 0.02, ang)), atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_braking_row_is_the_first_order_cbf_of_the_braking_barrier(seed):
    """A u - b = ḣ_b + κ h_b with h_b = h - s₊²/(2 a_b), ḣ_b by differences along the exact flow."""
    model = MODELS[3]
    rng = np.random.default_rng(seed)
    s = random_state(rng, model)
    u = rng.uniform(model.lo, model.hi)
    a1, a2 = 2.5, 1.5  # κ = k₁ = 1
    gains = np.array([[1.0, a1, a2]] * model.m)

    def hb(t: float) -> np.ndarray:
        st_ = model.integrate(s, u, t)
        return model.barrier(st_, FIELD.query(model.points(st_), hessian=True), model.h(st_, FIELD))

    sample = FIELD.query(model.points(s), hessian=True)
    a, b = model.rows(s, sample, model.h(s, FIELD), gains, np.zeros(3))
    eps = 1e-5
    rate = (hb(eps) - hb(-eps)) / (2 * eps)
    moving_in = -(sample.gradient @ s.velocity) > 1e-2  # away from the kink of s₊ at s = 0
    np.testing.assert_allclose((a @ u - b)[moving_in], (rate + 1.0 * hb(0.0))[moving_in], atol=1e-4)
    # The backup (a_max along the gradient, inside the box) never lets h_b drop at a convex
    # obstacle: ḣ_b = ḣ + (s/a_b)(a_max + vᵀ∇²d v) ≥ -s + s a_max/a_b ≥ 0.
    ub = model.backup(s, sample.gradient[0])
    assert np.all(np.abs(ub) <= model.hi + 1e-12)
    hb0 = model.barrier(s, sample, model.h(s, FIELD))
    assert (a[0] @ ub - b[0]) - 1.0 * hb0[0] >= -1e-9


@settings(max_examples=60, deadline=None)
@given(length=st.floats(0.1, 1.0), width=st.floats(0.05, 0.8), discs=st.integers(1, 6), capsule=st.booleans(),
       seed=st.integers(0, 2**31))
def test_disc_cover_contains_the_footprint(length, width, discs, capsule, seed):
    from riskfield.services.safety_filter.barriers import disc_cover

    o, r = disc_cover(length, width, discs, capsule)
    rng = np.random.default_rng(seed)
    p = rng.uniform([-length / 2, -width / 2], [length / 2, width / 2], (400, 2))
    p = np.concatenate([p, [[sx * length / 2, sy * width / 2] for sx in (-1, 1) for sy in (-1, 1)]])
    if capsule:  # keep the points of the rounded ends only
        seg = max(length - width, 0.0) / 2
        p = p[(np.abs(p[:, 0]) <= seg) | (np.hypot(np.abs(p[:, 0]) - seg, p[:, 1]) <= width / 2)]
    dist = np.linalg.norm(p[:, None, :] - o[None, :, :2], axis=2) - r[None]
    assert np.all(dist.min(axis=1) <= 1e-9)
