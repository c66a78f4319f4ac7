"""The barrier that sees motion: ∂h/∂t from tracked objects (``motion``, ``model``), both backends.

A person-sized obstacle (radius 0.22 m, inflated by the high group's 0.15 m margin as the mapper
does) in a planar ESDF, with a ``TrackedObject`` entry for it. Checks: the row with ∂h/∂t is the
barrier's true rate when the field moves with the object; an object moving away, standing, or
with a velocity below the deadband changes nothing; the moving one makes the filter brake
earlier, and the robot is stopped or backing away at the closest approach; a noisy velocity
estimate neither brakes for nothing nor makes the command oscillate; numpy and compiled agree.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import TrackedObject
from riskfield.services.fields import AnalyticField, to_esdf
from riskfield.services.geometry.shapes import Plane, Sphere
from riskfield.services.safety_filter import compiled
from riskfield.services.safety_filter import model as mdl
from riskfield.services.safety_filter.config import FilterConfig, MotionParams
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.model import OBJ_GROUP, OBJ_VX, OBJ_X
from riskfield.services.safety_filter.motion import effective_velocity, object_table
from riskfield.services.safety_filter.state import FilterState, so3_exp

GROUPS = ["high", "mid", "low"]
PERSON, MARGIN = 0.22, 0.15  # the simulator's person; the high group's inflation margin
P = MotionParams()


def person(x: float, y: float = 0.0, vx: float = 0.0, vy: float = 0.0, tracked_ms: float = 2000.0,
           age_ms: float = 0.0, risk_group: int = 1) -> TrackedObject:
    return TrackedObject(id=1, label=12, risk_group=risk_group, position=(x, y, 0.0), velocity=(vx, vy, 0.0),
                         radius=PERSON, age_ms=age_ms, tracked_ms=tracked_ms)


def scene(x: float, y: float = 0.0, planar: bool = True) -> AnalyticField:
    """The ESDF's view of a person at (x, y): a cylinder inflated by the margin, and a far wall."""
    return AnalyticField([Sphere((x, y, 0.0), PERSON + MARGIN, label=1, planar=planar),
                          Plane.through((0.0, -1.4, 0.0), (0.0, 1.0, 0.0), label=3)], groups=GROUPS)


def grid(x: float, y: float = 0.0, planar: bool = True):
    z = (0.0, 0.0) if planar else (-0.4, 0.4)
    return to_esdf(scene(x, y, planar), [-3.0, -1.5, z[0]], [4.5, 1.5, z[1]], 0.05, planar=planar)


def table(*objs: TrackedObject) -> np.ndarray:
    return object_table(list(objs), P, 0, 0)


# --------------------------------------------------------------------------- the velocity estimate


def test_deadband_cap_and_track_age_bound_the_velocity():
    assert not effective_velocity(person(0, vx=0.19), P).any()  # a standing person's jitter
    slow = effective_velocity(person(0, vx=0.3), P)[0]
    assert 0 < slow < 0.3 and slow == pytest.approx(0.3 * 0.5)  # ramping in: continuous, no switch
    assert effective_velocity(person(0, vx=-1.2), P)[0] == pytest.approx(-1.2)  # a walker counts fully
    assert np.linalg.norm(effective_velocity(person(0, vx=9.0, vy=9.0), P)) == pytest.approx(P.object_speed_cap)
    young = effective_velocity(person(0, vx=1.0, tracked_ms=75.0), P)[0]
    assert young == pytest.approx(0.25)  # a young track counts less
    assert not effective_velocity(person(0, vx=1.0, age_ms=P.object_stale_ms + 1), P).any()  # stale: nothing


@settings(max_examples=60, deadline=None)
@given(speed=st.floats(0.0, 3.0), eps=st.floats(1e-4, 1e-2))
def test_the_deadband_is_continuous(speed, eps):
    a = np.linalg.norm(effective_velocity(person(0, vx=speed), P))
    b = np.linalg.norm(effective_velocity(person(0, vx=speed + eps), P))
    assert abs(b - a) <= 3 * eps + 1e-12  # Lipschitz: a noisy speed cannot make the barrier jump


def test_the_table_keeps_what_moves_at_the_maps_stamp():
    objs = [person(1.0, vx=-1.0), person(2.0), person(3.0, vx=1.0, risk_group=0)]
    t = object_table(objs, P, esdf_stamp_ns=100_000_000, objects_stamp_ns=0)  # objects 0.1 s before the map
    assert t.shape == (1, 8)  # the standing one and the one without a group add nothing
    assert t[0, OBJ_X] == pytest.approx(0.9) and t[0, OBJ_VX] == pytest.approx(-1.0) and t[0, OBJ_GROUP] == 1
    many = object_table([person(float(x), vx=1.0) for x in range(20)], P, 0, 0, near=np.array([19.0, 0, 0]),
                        max_objects=4)
    assert sorted(many[:, OBJ_X].tolist()) == [16.0, 17.0, 18.0, 19.0]


# --------------------------------------------------------------------------- the rows


@pytest.mark.parametrize("model", ["unicycle", "single2d"])
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_the_row_is_the_barrier_rate_when_the_field_moves_with_the_object(model, seed):
    """A u - b = ḣ + α h with h(x, t) = d(p; the person at c + w t) - r, when the person comes closer."""
    rng = np.random.default_rng(seed)
    filt = SafetyFilter(FilterConfig(model=model, footprint={"shape": "none"}, predictive_rows=False,
                                     backend="numpy"))
    m = filt.model
    c = np.array([1.2, rng.uniform(-0.3, 0.3), 0.0])
    w = np.array([rng.uniform(-1.5, -0.3), rng.uniform(-0.5, 0.5), 0.0])
    s = FilterState.planar(rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(-0.5, 0.5))
    u = rng.uniform(m.lo, m.hi)
    field = scene(*c[:2])
    sample = field.query(m.points(s))
    h = sample.distance - m.radius
    row = table(person(c[0], c[1], w[0], w[1]))
    w = row[0, OBJ_VX:OBJ_VX + 3]  # the velocity the barrier uses (past the deadband's ramp)
    closing = np.zeros(m.m)
    gains = np.array([[1.0, 1.0, 1.0, MARGIN]] * m.m)
    mdl.closing_speeds(m.points(s), sample.distance, sample.gradient, sample.risk_group.astype(np.int64), gains, m.m,
                       row, 1, P.object_match_m, closing)
    assert closing[0] > 0  # the look-ahead point's nearest obstacle is the person, coming closer
    a, b = m.rows(s, sample, h, gains, np.zeros(3), closing)
    eps = 1e-6

    def h_at(t: float) -> np.ndarray:
        moved = scene(*(c + w * t)[:2])
        return m.h(m.integrate(s, u, t, np.zeros(3)), moved)

    rate = (h_at(eps) - h_at(-eps)) / (2 * eps)
    np.testing.assert_allclose(a @ u - b, rate + h, atol=1e-5)
    # Moving away: nothing (never looser than the static barrier).
    away = table(person(c[0], c[1], -w[0], w[1]))
    mdl.closing_speeds(m.points(s), sample.distance, sample.gradient, sample.risk_group.astype(np.int64), gains,
                       m.m, away, 1, P.object_match_m, closing)
    assert closing[0] == 0.0


MODELS = ["unicycle", "single2d", "single3d", "double3d"]


@pytest.mark.skipif(not compiled.HAVE_NUMBA, reason="numba is not installed")
@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_compiled_and_numpy_agree_with_moving_objects(model, seed):
    rng = np.random.default_rng(seed)
    planar = model in ("unicycle", "single2d")
    c = rng.uniform([0.6, -0.5], [1.6, 0.5])
    field = grid(c[0], c[1], planar)
    cfg = {"model": model, "predictive_rows": bool(rng.random() < 0.8), "margins_in_filter": bool(rng.random() < 0.3)}
    fast, slow = SafetyFilter(FilterConfig(**cfg, backend="numba")), SafetyFilter(FilterConfig(**cfg, backend="numpy"))
    objs = table(person(c[0], c[1], *rng.normal(0, 1.0, 2)), person(*rng.uniform(-1, 3, 2), *rng.normal(0, 1, 2)))
    age = float(rng.uniform(0, 0.3))
    for _ in range(20):
        p = rng.uniform([-0.6, -1.0, -0.3], [1.8, 1.0, 0.3])
        v = tuple(rng.normal(0, 0.5, 3))
        s = (FilterState.planar(p[0], p[1], rng.uniform(-math.pi, math.pi), velocity=v) if planar
             else FilterState(p, so3_exp(rng.normal(0, 0.5, 3)), np.array(v)))
        u_ref = rng.uniform(fast.model.lo, fast.model.hi)
        ang = rng.normal(0, 1.0, 3)
        a, b = fast.filter(s, u_ref, field, ang, objs, age), slow.filter(s, u_ref, field, ang, objs, age)
        assert_same(a, b)


def assert_same(a, b) -> None:
    """As ``test_compiled``: every discrete outcome equal, floats to rounding."""
    assert (a.fallback, a.risk_group, a.intervening, a.rows, a.solver) == (b.fallback, b.risk_group, b.intervening,
                                                                          b.rows, b.solver)
    assert a.h == pytest.approx(b.h, abs=1e-9) and a.margin == pytest.approx(b.margin, abs=1e-9)
    np.testing.assert_allclose(a.u, b.u, atol=1e-9, rtol=0)


def test_static_scenes_give_the_same_command_as_without_objects():
    field = grid(1.0)
    for backend in ("numba", "numpy") if compiled.HAVE_NUMBA else ("numpy",):
        filt = SafetyFilter(FilterConfig(backend=backend))
        off = SafetyFilter(FilterConfig(backend=backend, object_motion=False))
        standing = table(person(1.0, vx=0.1))  # below the deadband: no rows at all
        assert len(standing) == 0
        zero = np.array([[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, PERSON, 1.0]])  # a row that moves nothing
        away = table(person(1.0, vx=1.2))  # moving away from a robot at the origin
        for x in np.linspace(-0.4, 0.3, 15):
            s = FilterState.planar(x, 0.05, 0.1)
            u = np.array([0.6, 0.2])
            ref = filt.filter(s, u, field)
            for objs in (None, standing, zero, away):
                for f in (filt, off):
                    got = f.filter(s, u, field, None, objs, 0.2)
                    assert got.u.tolist() == ref.u.tolist() and got.margin == ref.margin and got.rows == ref.rows


def test_an_approaching_person_makes_the_filter_brake_earlier():
    filt = SafetyFilter(FilterConfig())
    field = grid(2.0)
    s = FilterState.planar(0.0, 0.0, 0.0)
    u = np.array([0.5, 0.0])
    static = filt.filter(s, u, field)
    coming = filt.filter(s, u, field, None, table(person(2.0, vx=-1.2)), 0.1)
    assert static.u[0] == pytest.approx(0.5) and not static.intervening  # 1.2 m of clearance: it drives on
    assert coming.u[0] < 0.5 - 0.2 and coming.intervening and coming.fallback is None
    assert coming.margin < static.margin  # the person has come v·age closer since the map


# --------------------------------------------------------------------------- closed loop


def head_on(motion: bool, noise: float = 0.0, seed: int = 0, person_speed: float = 1.2, steps: int = 150,
            lag: int = 5) -> dict:
    """A LIMO drives at 0.5 m/s towards a person who walks head-on at ``person_speed`` until 5 cm
    from its body, then stands (the issue's head-on case). Maps come at 10 Hz (every 5th 50 Hz
    step), showing the person ``lag`` steps late (0.1 s: the pipeline's latency), with the
    tracker's velocity estimate (± ``noise`` m/s per axis); the filter adds the motion since the
    map's stamp itself."""
    rng = np.random.default_rng(seed)
    filt = SafetyFilter(FilterConfig(object_motion=motion))
    dt = filt.config.dt
    s = FilterState.planar(0.0, 0.0, 0.0)
    x_p, walking, log = 3.2, True, []
    field = objs = None
    since = 0.0
    past = [(x_p, -person_speed)] * (lag + 1)  # (position, velocity) lag steps ago
    for k in range(steps):
        v_true = -person_speed if walking else 0.0
        past = [*past[1:], (x_p, v_true)]
        if k % 5 == 0:
            x_map, v_map = past[0]
            field = grid(x_map)
            objs = table(person(x_map, vx=v_map + rng.normal(0, noise), vy=rng.normal(0, noise)))
            since = lag * dt
        res = filt.filter(s, np.array([0.5, 0.0]), field, None, objs, since)
        s = filt.model.integrate(s, res.u, dt)
        x_p += v_true * dt
        since += dt
        body = filt.model.points(s)[1:]  # the footprint's discs
        gap = float((np.hypot(body[:, 0] - x_p, body[:, 1]) - PERSON - filt.model.radius[1:]).min())
        walking = walking and gap > 0.05
        log.append((k * dt, float(res.u[0]), gap, res.fallback))
    arr = np.array([(t, v, g) for t, v, g, _ in log])
    k = int(np.argmin(arr[:, 2]))
    first = next((t for t, v, _, _ in log if v < 0.45), math.inf)
    return {"v": arr[:, 1], "gap": arr[:, 2], "closest": k, "v_closest": arr[k, 1], "first_brake": first,
            "fallbacks": {f for *_, f in log}, "log": log}


def test_head_on_the_robot_is_stopped_or_retreating_at_closest_approach():
    moving, static = head_on(True), head_on(False)
    assert moving["first_brake"] < static["first_brake"]  # it slows earlier than the static barrier
    assert moving["v_closest"] <= 0.01, moving["v_closest"]  # stopped or backing away, not pushing in
    assert moving["gap"].min() > static["gap"].min() + 0.3  # it keeps its distance; the static one lets them close
    assert moving["fallbacks"] <= {None, "slack"}


def test_a_noisy_estimate_of_a_standing_person_brakes_for_nothing_never():
    quiet = head_on(True, person_speed=0.0)
    base = head_on(False, person_speed=0.0)
    np.testing.assert_array_equal(quiet["v"], base["v"])  # the same commands as the static barrier
    for seed in range(3):  # ±0.08 m/s per axis: |v| stays below the deadband nearly always
        noisy = head_on(True, noise=0.08, seed=seed, person_speed=0.0)
        assert np.abs(noisy["v"] - base["v"]).max() < 0.05
        assert noisy["gap"].min() >= base["gap"].min() - 1e-9


def test_a_noisy_estimate_of_a_walker_does_not_make_the_command_oscillate():
    # ±0.1 m/s per axis at every map: the estimate's accuracy the tracker is held to (issue 23:
    # within 0.15 m/s after 5 maps).
    clean = head_on(True)
    for seed in range(4):
        noisy = head_on(True, noise=0.1, seed=seed)
        assert noisy["v_closest"] <= 0.01
        # Oscillation would be a robot that backs away and drives back in while the person keeps
        # coming: once it backs away it never commands forward again, and the command stays near
        # the clean estimate's (the barrier is Lipschitz in the velocity).
        k0 = int(np.argmax(noisy["v"] < 0))
        assert k0 > 0 and (noisy["v"][k0:] <= 0.01).all()
        assert np.abs(noisy["v"] - clean["v"]).mean() < 0.25


def test_missing_or_stale_objects_give_the_static_barrier_counted_not_a_brake():
    from riskfield.protocol import Header, TrackedObjects, VelocityCommand
    from riskfield.services.safety_filter.supervisor import FilterSupervisor

    def supervisor(motion: bool = True) -> FilterSupervisor:
        sup = FilterSupervisor(SafetyFilter(FilterConfig(object_motion=motion)), 0.3, 10.0, 10.0)
        sup.on_map(grid(1.6), 0.0)
        sup.on_state(FilterState.planar(0.0, 0.0, 0.0), 0.0)
        sup.on_ref(VelocityCommand(linear=(0.5, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="op"), 0.0)
        return sup

    coming = TrackedObjects(header=Header(stamp_ns=0), objects=[person(1.6, vx=-1.2)])
    static = supervisor(False).tick(0.1)[0]
    sup = supervisor()
    cmd, status = sup.tick(0.1)
    assert sup.motion == "missing" and sup.counts["objects_missing"] == 1 and status.fallback is None
    assert cmd.linear == static.linear
    sup.on_objects(coming, 0.1)
    cmd, status = sup.tick(0.15)
    assert sup.motion == "ok" and cmd.linear[0] < static.linear[0] - 0.2 and status.fallback is None
    sup.on_map(grid(1.6), 0.45)
    cmd, status = sup.tick(0.5)  # the objects arrived 0.4 s ago: stale (the map timeout is 0.3 s)
    assert sup.motion == "stale" and sup.counts["objects_stale"] == 1 and status.fallback is None
    assert cmd.linear == static.linear
    sup.on_objects(None, 0.5)  # an unusable message
    assert sup.tick(0.5)[0].linear == static.linear and sup.motion == "missing"
