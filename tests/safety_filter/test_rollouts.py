"""Closed-loop rollouts: h = d - r never goes negative with the exact dynamics at 50 Hz.

Each rollout starts at a random state in the filter's safe set (h - δ ≥ 0; for the double
integrator also ψ₁ = ḣ + k h ≥ 0), near obstacles of different risk groups, and follows an
adversarial reference (aimed at the nearest obstacle, re-drawn every 10 steps). The input is
held for the control period and the state advanced by the model's exact solution; h is
checked at every sample and half-way in between. The same rollouts without the
filter must collide, or the test would prove nothing.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskfield.services.fields import AnalyticField, to_esdf
from riskfield.services.geometry.shapes import Plane, Sphere
from riskfield.services.safety_filter.barriers import DoubleIntegrator, SingleIntegrator
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.state import FilterState, so3_exp

GROUPS = ["high", "mid", "low"]
STEPS = 30


def scene(planar: bool) -> AnalyticField:
    """A high-risk and a low-risk obstacle side by side and a mid-risk wall: ridges included."""
    return AnalyticField([
        Sphere([1.0, 0.0, 0.0], 0.3, planar=planar, label=1),
        Sphere([0.95, 0.75, 0.0], 0.25, planar=planar, label=3),
        Plane.through([0.0, -0.7, 0.0], [0.0, 1.0, 0.0], label=2),
    ], groups=GROUPS)


def start_state(rng, filt: SafetyFilter, field, planar: bool, truth: AnalyticField) -> FilterState:
    """A random state in the safe set of every obstacle of ``truth`` (for the double integrator
    a state that is safe for the nearest obstacle only may already be unable to stop before the
    next one: that is outside every CBF's promise)."""
    model = filt.model
    while True:
        p = rng.uniform([-0.3, -0.65, -0.3], [2.0, 1.4, 0.3])
        if planar:
            p[2] = 0.0
        if planar or isinstance(model, DoubleIntegrator):
            s = FilterState.planar(p[0], p[1], rng.uniform(-math.pi, math.pi), p[2])
        else:
            s = FilterState(p, so3_exp(rng.normal(0, 0.6, 3)))
        if isinstance(model, DoubleIntegrator):
            s = FilterState(s.position, s.rotation, rng.normal(0, 0.4, 3))
        sample = field.query(model.points(s))
        hb = sample.distance - model.radius - filt.delta
        if hb.min() < 0 or hb.min() > 0.4:
            continue  # start in the safe set, close enough for the obstacles to matter
        if isinstance(model, DoubleIntegrator):
            # Able to stop: braking at a_b keeps every obstacle's h - δ ≥ 0 (the braking barrier).
            safe = True
            for part in truth.shapes:
                ps = AnalyticField(part, truth.groups).query(model.points(s))
                hb_part = ps.distance - model.radius - filt.delta
                safe &= bool(model.barrier(s, ps, hb_part, gains=filt.gains_at(truth, ps)).min() >= 0)
            if not safe:
                continue
        return s


def reference(rng, filt: SafetyFilter, field, s: FilterState, cfg: FilterConfig) -> tuple[np.ndarray, np.ndarray]:
    """(u_ref or desired velocity, passed-through angular velocity), aimed at the nearest obstacle."""
    model = filt.model
    toward = -field.query(model.points(s)[:1]).gradient[0]
    ang = np.zeros(3)
    if model.name == "unicycle":
        return np.array([rng.uniform(0.3, 1.0), rng.uniform(-2.0, 2.0)]), ang
    if isinstance(model, SingleIntegrator):
        body = s.rotation.T @ toward
        u = body[: model.dim] / max(np.linalg.norm(body[: model.dim]), 1e-9) * rng.uniform(0.4, 1.4)
        u += rng.normal(0, 0.3, model.dim)
        ang = np.array([0.0, 0.0, rng.uniform(-2, 2)]) if model.dim == 2 else rng.normal(0, 0.8, 3)
        return u, ang
    return toward * rng.uniform(0.4, 1.0), ang  # double integrator: a desired world velocity


def rollouts(model_name: str, field, n: int, seed: int, filtered: bool = True,
             truth: AnalyticField | None = None) -> dict:
    cfg = FilterConfig(model=model_name)
    filt = SafetyFilter(cfg)
    model = filt.model
    planar = model_name in ("unicycle", "single2d")
    rng = np.random.default_rng(seed)
    worst = math.inf
    collided = intervened = fallbacks = 0
    dt = cfg.dt
    for _ in range(n):
        s = start_state(rng, filt, field, planar, truth or field)
        hit = touched = False
        for k in range(STEPS):
            if k % 10 == 0:
                ref, ang = reference(rng, filt, field, s, cfg)
            u_ref = cfg.k_v * (ref - s.velocity) if isinstance(model, DoubleIntegrator) else ref
            if filtered:
                res = filt.filter(s, u_ref, field, ang)
                assert np.isfinite(res.u).all()
                fallbacks += res.fallback is not None
                touched |= res.intervening
                u = res.u
            else:
                u = np.clip(u_ref, model.lo, model.hi)
            # h half-way between the samples (same held input) and at the next sample.
            between = model.points(model.integrate(s, u, 0.5 * dt, ang))
            s = model.integrate(s, u, dt, ang)
            h = (field.query(np.concatenate([between, model.points(s)])).distance - np.tile(model.radius, 2)).min()
            worst = min(worst, h)
            hit |= h < 0
        collided += hit
        intervened += touched
    return dict(worst=worst, collided=collided, intervened=intervened, fallbacks=fallbacks)


@pytest.mark.slow  # ~1 min for the four models; the 60-rollout grid test below keeps the claim in `make check`
@pytest.mark.parametrize("model_name", ["unicycle", "single2d", "single3d", "double3d"])
def test_a_thousand_rollouts_never_violate_h(model_name):
    field = scene(planar=model_name in ("unicycle", "single2d"))
    out = rollouts(model_name, field, 1000, seed=11)
    assert out["worst"] >= 0.0, out
    assert out["collided"] == 0, out
    assert out["fallbacks"] == 0, out  # the safe set stays feasible: no braking needed
    assert out["intervened"] > 500, out  # most rollouts needed the filter
    unfiltered = rollouts(model_name, field, 200, seed=11, filtered=False)
    assert unfiltered["collided"] > 25, unfiltered  # the references are dangerous


@pytest.mark.parametrize("model_name", ["unicycle", "single2d", "single3d", "double3d"])
def test_rollouts_on_a_real_grid_never_violate_h(model_name):
    planar = model_name in ("unicycle", "single2d")
    truth = scene(planar)
    grid = to_esdf(truth, [-1.0, -1.0, -0.6 if not planar else 0.0], [3.0, 2.0, 0.6], 0.04, planar=planar)
    out = rollouts(model_name, grid, 60, seed=5, truth=truth)
    assert out["collided"] == 0 and out["worst"] >= 0.0, out
    assert out["intervened"] > 20, out
    # Against the true geometry the grid's interpolation error (< 1 cm here) is what remains.
    filt = SafetyFilter(FilterConfig(model=model_name))
    assert filt.delta > 0.01
