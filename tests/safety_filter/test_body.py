"""The whole body stays clear in closed loop: random layouts of boxes and
spheres on analytic fields, random states from which the robot can still stop (half of them
within twice the stopping distance of an obstacle), random references, every model with its
bounds, 200 steps of the exact dynamics at 50 Hz. The body's clearance — the true distance of
every footprint disc's centre minus its radius, checked at every sample and half-way in
between — never goes below zero.

"Can still stop" is measured with the filter's own barrier: for the double integrator braking
at a_b along the gradient keeps every obstacle's d - r - δ ≥ 0 (``DoubleIntegrator.barrier``);
velocity-controlled models stop at once in their kinematics (the α cap covers the platform's
deceleration), so there every disc only needs d - r - δ ≥ 0. The look-ahead point of the
unicycle is not part of the body: it may start inside its margin (the slack path then runs).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from riskfield.protocol import RiskConfig, ade20k
from riskfield.services.fields import AnalyticField, EsdfField
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Sphere, render
from riskfield.services.geometry.transforms import look_at
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.mapper import Mapper
from riskfield.services.safety_filter.barriers import DoubleIntegrator, SingleIntegrator
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.state import FilterState, so3_exp

GROUPS = ["high", "mid", "low"]
MODELS = ["unicycle", "single2d", "single3d", "double3d"]
STEPS = 200


def layout(rng: np.random.Generator, planar: bool) -> AnalyticField:
    """2-4 boxes and spheres of random groups scattered over a 3 m × 3 m room."""
    parts: list[Box | Sphere] = []
    for _ in range(rng.integers(2, 5)):
        c = [*rng.uniform(0.0, 3.0, 2), 0.0 if planar else rng.uniform(-0.3, 0.3)]
        group = int(rng.integers(1, 4))
        if rng.random() < 0.5:
            half = rng.uniform(0.1, 0.5, 3)
            if planar:  # extruded along z, as the planar models see it
                half[2] = 9.0
            parts.append(Box(tuple(np.subtract(c, half)), tuple(np.add(c, half)), label=group))
        else:
            parts.append(Sphere(tuple(c), float(rng.uniform(0.1, 0.4)), label=group, planar=planar))
    return AnalyticField(parts, groups=GROUPS)


def body(filt: SafetyFilter) -> slice:
    """The footprint's discs among the barrier points (the unicycle's look-ahead point is first)."""
    return slice(1, None) if filt.model.name == "unicycle" else slice(None)


def clearance(filt: SafetyFilter, field: AnalyticField, s: FilterState) -> float:
    b = body(filt)
    return float((field.query(filt.model.points(s)[b]).distance - filt.model.radius[b]).min())


def stopping_distance(filt: SafetyFilter, s: FilterState) -> float:
    model = filt.model
    if isinstance(model, DoubleIntegrator):
        return float(s.velocity @ s.velocity) / (2 * model.a_brake)
    return float(model.hi[0]) ** 2 / (2 * filt.config.a_max)  # the platform's stop from full speed


def can_stop(filt: SafetyFilter, field: AnalyticField, s: FilterState, whole: bool = False) -> bool:
    """Every disc (with ``whole``, also the look-ahead point) inside the filter's safe set."""
    model, b = filt.model, slice(None) if whole else body(filt)
    for part in field.shapes:
        ps = AnalyticField(part, field.groups).query(model.points(s), hessian=model.needs_hessian)
        hb = ps.distance - model.radius - filt.delta
        if model.barrier(s, ps, hb, gains=filt.gains_at(field, ps))[b].min() < 0:
            return False
    return True


def start(rng: np.random.Generator, filt: SafetyFilter, field: AnalyticField, near: bool) -> FilterState | None:
    model = filt.model
    planar = model.name in ("unicycle", "single2d")
    for _ in range(2000):
        p = rng.uniform(-0.5, 3.5, 3)
        p[2] = 0.0 if planar else rng.uniform(-0.3, 0.3)
        if model.name == "single3d":
            s = FilterState(p, so3_exp(rng.normal(0, 0.5, 3)))
        else:
            s = FilterState.planar(p[0], p[1], rng.uniform(-math.pi, math.pi), p[2])
        if isinstance(model, DoubleIntegrator):
            s = FilterState(s.position, s.rotation, rng.normal(0, 1, 3) / math.sqrt(3) * rng.uniform(0, 1))
        if not can_stop(filt, field, s):
            continue
        if near and clearance(filt, field, s) > 2 * stopping_distance(filt, s) + filt.delta:
            continue
        return s
    return None


def reference(rng: np.random.Generator, filt: SafetyFilter, field: AnalyticField, s: FilterState):
    """(reference input or desired velocity, passed-through angular velocity)."""
    model = filt.model
    toward = -field.query(model.points(s)[body(filt)][:1]).gradient[0]
    aim = toward if rng.random() < 0.6 else rng.normal(0, 1, 3)
    if model.name == "unicycle":
        return np.array([rng.uniform(-1, 1), rng.uniform(-2, 2)]), np.zeros(3)
    if isinstance(model, SingleIntegrator):
        local = s.rotation.T @ aim
        u = local[: model.dim] / max(np.linalg.norm(local[: model.dim]), 1e-9) * rng.uniform(0.3, 1.4)
        ang = np.array([0.0, 0.0, rng.uniform(-2, 2)]) if model.dim == 2 else rng.normal(0, 0.8, 3)
        return u, ang
    return aim / max(np.linalg.norm(aim), 1e-9) * rng.uniform(0.3, 1.0), np.zeros(3)


def closed_loop(filt: SafetyFilter, field: AnalyticField, s: FilterState, rng: np.random.Generator,
                filtered: bool = True) -> dict:
    model, dt = filt.model, filt.config.dt
    worst, slack, brakes, touched = math.inf, 0, 0, False
    for k in range(STEPS):
        if k % 20 == 0:
            ref, ang = reference(rng, filt, field, s)
        u_ref = model.k_v * (ref - s.velocity) if isinstance(model, DoubleIntegrator) else ref
        if filtered:
            res = filt.filter(s, u_ref, field, ang)
            assert np.isfinite(res.u).all() and np.all(res.u >= model.lo - 1e-9) and np.all(res.u <= model.hi + 1e-9)
            slack += res.fallback == "slack"
            brakes += res.fallback not in (None, "slack")
            touched |= res.intervening
            u = res.u
        else:
            u = np.clip(u_ref, model.lo, model.hi)
        mid = model.integrate(s, u, 0.5 * dt, ang)
        s = model.integrate(s, u, dt, ang)
        worst = min(worst, clearance(filt, field, mid), clearance(filt, field, s))
    return dict(worst=worst, slack=slack, brakes=brakes, intervened=touched)


@pytest.mark.parametrize("model_name", MODELS)
@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31), near=st.booleans())
def test_the_body_never_touches_an_obstacle(model_name, seed, near):
    rng = np.random.default_rng(seed)
    filt = SafetyFilter(FilterConfig(model=model_name))
    field = layout(rng, planar=model_name in ("unicycle", "single2d"))
    s = start(rng, filt, field, near)
    if s is None:
        return  # no stoppable start in this layout (rare: the room is crowded)
    in_safe_set = can_stop(filt, field, s, whole=True)
    out = closed_loop(filt, field, s, rng)
    assert out["worst"] >= 0.0, out
    assert out["brakes"] == 0, out  # fresh analytic data: never a blind brake
    if in_safe_set:
        assert out["slack"] == 0, out  # from the safe set the QP stays feasible within the bounds


@pytest.mark.parametrize("model_name", MODELS)
def test_the_same_rollouts_without_the_filter_collide(model_name):
    """Otherwise the property above would prove nothing: of 30 near starts at least 8 collide
    unfiltered and the filter acts on at least 15 (the seeds stop once both are shown)."""
    hits = touched = 0
    for seed in range(30):
        if hits >= 8 and touched >= 15:
            break
        rng = np.random.default_rng(seed)
        filt = SafetyFilter(FilterConfig(model=model_name))
        field = layout(rng, planar=model_name in ("unicycle", "single2d"))
        s = start(rng, filt, field, near=True)
        assert s is not None
        state = rng.bit_generator.state
        hits += closed_loop(filt, field, s, rng, filtered=False)["worst"] < 0
        rng.bit_generator.state = state  # the same references for the filtered run
        out = closed_loop(filt, field, s, rng)
        assert out["worst"] >= 0.0, (seed, out)
        touched += out["intervened"]
    assert hits >= 8, hits
    assert touched >= 15, touched


# -- the same property on fields the mapper builds ------------------------------------------------
# The same property on fields the mapper builds: random boxes and spheres are rendered from
# views round the room, integrated by the real ``Mapper`` (solid obstacles, exact margins), and the
# filter drives on the published ESDF for 200 steps from states it can stop from, with random
# references. The body's clearance, measured on the *true* geometry, never goes below zero.
#
# Ground models (unicycle, single2d) read the 2-D slice, the others the 3-D grid; all use
# the node's defaults (footprint, braking barrier, B-spline field, slack fallback). The helpers
# (start states, references, closed loop) are those of the analytic-field property test.

CAMERA = PinholeCamera.centred(120, 90, 60.0)  # 90° wide: a whole object side per view
CENTRE = np.array([1.5, 1.5, 0.0])
LABELS = [ade20k.index("person"), ade20k.index("chair"), ade20k.index("box")]  # high, mid, low


def no_margins() -> RiskConfig:
    """Margins off: the body must clear the geometry itself, so every mapping error would show."""
    r = RiskConfig()
    return r.model_copy(update={"groups": [g.model_copy(update={"margin": 0.0}) for g in r.groups]})


def mapped_layout(rng: np.random.Generator, planar: bool) -> tuple[list, AnalyticField]:
    """2-3 obstacles standing on the floor in a 3 m room: what the camera sees, and the truth the
    clearance is measured on (for the planar robot, the shapes extruded along z, as the slice is)."""
    seen, truth = [], []
    for _ in range(rng.integers(2, 4)):
        x, y = rng.uniform(0.6, 2.4, 2)
        label = int(rng.choice(LABELS))
        group = 1 + LABELS.index(label)
        if rng.random() < 0.5 or planar:
            hx, hy, h = rng.uniform(0.12, 0.3), rng.uniform(0.12, 0.3), rng.uniform(0.5, 0.9)
            seen.append(Box((x - hx, y - hy, 0.0), (x + hx, y + hy, h), label=label))
            truth.append(Box((x - hx, y - hy, -9.0 if planar else 0.0), (x + hx, y + hy, 9.0 if planar else h),
                             label=group))
        else:
            r = rng.uniform(0.15, 0.3)
            z = rng.uniform(r, 0.6)
            seen.append(Sphere((x, y, z), r, label=label))
            truth.append(Sphere((x, y, z), r, label=group))
    return seen, AnalyticField(truth, groups=GROUPS)


def mapped(scene: list, planar: bool) -> EsdfField:
    """The ESDF the mapper publishes after views from eight directions round the room."""
    cfg = MapperConfig(voxel_size=0.05, half_extent=(1.8, 1.8, 0.8), output="2d" if planar else "3d",
                       pixel_stride=1, max_distance=1.0, recentre_distance=100.0)
    mapper = Mapper(cfg, no_margins())
    mapper.set_robot_position(CENTRE)
    for a in np.linspace(0, 2 * math.pi, 8, endpoint=False):
        for height in (0.25, 0.9):
            eye = CENTRE + np.array([2.2 * math.cos(a), 2.2 * math.sin(a), height])
            T = look_at(eye, CENTRE + np.array([0.0, 0.0, 0.35]))
            mapper.integrate(*render(scene, T, CAMERA), T)
    up = mapper.update_esdf()
    assert up is not None
    grid = up.slice2d if planar else up.grid3d
    assert grid is not None
    return EsdfField.from_grid(grid)


def mapped_start(rng: np.random.Generator, filt: SafetyFilter, truth: AnalyticField, field: EsdfField,
                 near: bool) -> FilterState | None:
    """A state the robot can stop from (on the truth, and in the filter's own view of the map)."""
    model = filt.model
    planar = model.name in ("unicycle", "single2d")
    for _ in range(2000):
        p = np.array([*rng.uniform(0.2, 2.8, 2), 0.0 if planar else rng.uniform(0.2, 0.7)])
        s = FilterState.planar(p[0], p[1], rng.uniform(-math.pi, math.pi), p[2])
        if isinstance(model, DoubleIntegrator):
            s = FilterState(s.position, s.rotation, rng.normal(0, 1, 3) / math.sqrt(3) * rng.uniform(0, 0.8))
        if not (can_stop(filt, truth, s) and field.query(model.points(s)).inside.all()):
            continue
        q = field.query(model.points(s)[body(filt)])
        if (q.distance - model.radius[body(filt)] - filt.delta).min() < stopping_distance(filt, s):
            continue  # the map, not only the truth, must leave room to stop
        clear = (truth.query(model.points(s)[body(filt)]).distance - model.radius[body(filt)]).min()
        if near and clear > 2 * stopping_distance(filt, s) + filt.delta + 0.1:
            continue
        return s
    return None


def true_clearance(filt: SafetyFilter, truth: AnalyticField, s: FilterState) -> float:
    b = body(filt)
    return float((truth.query(filt.model.points(s)[b]).distance - filt.model.radius[b]).min())


@pytest.mark.parametrize("model_name", MODELS)
@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31), near=st.booleans())
def test_the_body_never_touches_what_the_mapper_mapped(model_name, seed, near):
    rng = np.random.default_rng(seed)
    planar = model_name in ("unicycle", "single2d")
    filt = SafetyFilter(FilterConfig(model=model_name), no_margins())
    scene, truth = mapped_layout(rng, planar)
    field = mapped(scene, planar)
    s = mapped_start(rng, filt, truth, field, near)
    if s is None:
        return  # no stoppable start in this layout (rare)
    model, dt = filt.model, filt.config.dt
    worst = math.inf
    for k in range(STEPS):
        if k % 20 == 0:
            ref, ang = reference(rng, filt, truth, s)
        u_ref = model.k_v * (ref - s.velocity) if isinstance(model, DoubleIntegrator) else ref
        res = filt.filter(s, u_ref, field, ang)
        assert np.isfinite(res.u).all()
        if res.fallback == "outside_map":
            break  # it left the mapped room: the node brakes there, nothing more to check
        mid = model.integrate(s, res.u, 0.5 * dt, ang)
        s = model.integrate(s, res.u, dt, ang)
        worst = min(worst, true_clearance(filt, truth, mid), true_clearance(filt, truth, s))
    assert worst >= 0.0, worst
