"""The CLF laws converge from random starts and their Lyapunov functions decrease."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.geometry.transforms import wrap_angle
from riskfield.services.navigator.clf import PointMassCLF, UnicycleCLF, clip_norm

coord = st.floats(-3.0, 3.0, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)


def simulate_unicycle(ctrl: UnicycleCLF, p: np.ndarray, yaw: float, goal: np.ndarray, dt: float, steps: int):
    vs = []
    for _ in range(steps):
        v, w = ctrl.command(p, yaw, goal)
        vs.append(ctrl.lyapunov(p, yaw, goal))
        p = p + dt * v * np.array([math.cos(yaw), math.sin(yaw)])
        yaw = wrap_angle(yaw + dt * w)
    return p, yaw, np.array(vs)


@settings(max_examples=40, deadline=None)
@given(coord, coord, angle, coord, coord)
def test_unicycle_converges_and_v_decreases(x, y, yaw, gx, gy):
    ctrl = UnicycleCLF()
    goal = np.array([gx, gy])
    p, _, vs = simulate_unicycle(ctrl, np.array([x, y]), yaw, goal, dt=0.01, steps=6000)
    assert np.linalg.norm(p - goal) < 0.02
    # V̇ ≤ 0 in continuous time; in discrete time allow O(dt²) per step.
    assert np.all(np.diff(vs) <= 1e-3)


def test_unicycle_respects_limits_and_never_reverses_by_default():
    ctrl = UnicycleCLF(v_max=0.3, w_max=1.0)
    rng = np.random.default_rng(0)
    for _ in range(500):
        v, w = ctrl.command(rng.uniform(-5, 5, 2), rng.uniform(-4, 4), rng.uniform(-5, 5, 2))
        assert 0.0 <= v <= 0.3 + 1e-12
        assert abs(w) <= 1.0 + 1e-12


def test_unicycle_goal_behind_turns_in_place_first():
    v, w = UnicycleCLF().command(np.zeros(2), 0.0, np.array([-1.0, 0.01]))
    assert v == 0.0 and w > 0.5


def test_unicycle_reverse_when_allowed():
    v, w = UnicycleCLF(allow_reverse=True).command(np.zeros(2), 0.0, np.array([-1.0, 0.0]))
    assert v < 0 and abs(w) < 1e-9


@settings(max_examples=40, deadline=None)
@given(st.lists(coord, min_size=3, max_size=3), st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3),
       st.lists(coord, min_size=3, max_size=3))
def test_double_integrator_converges(p0, v0, g):
    ctrl = PointMassCLF()
    p, v, goal = np.array(p0), np.array(v0), np.array(g)
    dt = 0.01
    for _ in range(3000):
        u = ctrl.command(p, v, goal)
        assert np.linalg.norm(u) <= ctrl.a_max + 1e-9
        p, v = p + dt * v + 0.5 * dt * dt * u, v + dt * u
    assert np.linalg.norm(p - goal) < 0.02
    assert np.linalg.norm(v) < 0.02


def test_double_integrator_energy_decreases_when_unsaturated():
    ctrl = PointMassCLF(v_max=100.0, a_max=100.0)
    p, v, goal, dt = np.array([0.3, -0.2, 0.1]), np.array([0.1, 0.0, -0.1]), np.zeros(3), 1e-3
    energies = []
    for _ in range(3000):
        energies.append(ctrl.lyapunov(p, v, goal))
        u = ctrl.command(p, v, goal)
        np.testing.assert_allclose(u, -ctrl.k_p * p - ctrl.k_d * v, atol=1e-12)  # the PD law
        p, v = p + dt * v, v + dt * u
    assert np.all(np.diff(energies) <= 1e-7)
    assert energies[-1] < 0.05 * energies[0]


def test_double_integrator_cruise_speed_is_bounded():
    ctrl = PointMassCLF(v_max=0.5, a_max=1.0)
    p, v, goal, dt = np.zeros(3), np.zeros(3), np.array([10.0, 0, 0]), 0.01
    speeds = []
    for _ in range(1500):
        u = ctrl.command(p, v, goal)
        p, v = p + dt * v, v + dt * u
        speeds.append(np.linalg.norm(v))
    assert max(speeds) <= 0.5 + 1e-6
    assert speeds[-1] > 0.45


def test_batch_matches_single():
    ctrl = PointMassCLF()
    rng = np.random.default_rng(1)
    p, v, g = rng.normal(size=(20, 3)), rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    batch = ctrl.command_batch(p, v, g)
    for i in range(20):
        np.testing.assert_allclose(batch[i], ctrl.command(p[i], v[i], g[i]), atol=1e-12)


def test_clip_norm_keeps_direction():
    x = clip_norm(np.array([3.0, 4.0]), 1.0)
    np.testing.assert_allclose(x, [0.6, 0.8])
    np.testing.assert_array_equal(clip_norm(np.array([0.1, 0.0]), 1.0), [0.1, 0.0])
