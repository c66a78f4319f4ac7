"""The filter's compiled step (``safety_filter.compiled``) against its numpy rendering
(``oracles.filter_step``) and OSQP.

Tolerance: the compiled kernel sums in another order than numpy's BLAS calls, so floats agree
to rounding (1e-9 here), and every discrete outcome (fallback, risk group, rows, intervening) is
the same. The scenes avoid walls aligned with a grid axis: there the slack-relaxed row of the
double integrator can be parallel to a face of the input box and exactly at the edge of
feasibility, where the last bit of a dot product decides between two admissible answers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.filter_step import ReferenceFilter
from riskfield.protocol import EsdfGrid, decode, encode
from riskfield.services.fields import AnalyticField, EsdfField, to_esdf
from riskfield.services.fields.analytic import to_grid_message
from riskfield.services.geometry.shapes import Plane, Sphere
from riskfield.services.safety_filter import compiled
from riskfield.services.safety_filter.barriers import BarrierModel
from riskfield.services.safety_filter.config import FilterConfig, Footprint
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.model import ModelSpec
from riskfield.services.safety_filter.state import FilterState, so3_exp

pytestmark = pytest.mark.skipif(not compiled.HAVE_NUMBA, reason="numba is not installed")

GROUPS = ["high", "mid", "low"]
MODELS = ["unicycle", "single2d", "single3d", "double3d"]
INTERPOLATIONS = ["trilinear", "catmull_rom", "bspline", "bspline_smooth"]


def random_field(rng: np.random.Generator, planar: bool, interpolation: str) -> EsdfField:
    shapes = [Sphere(tuple(rng.uniform([0.3, -0.6, -0.2], [1.5, 0.6, 0.2])), float(rng.uniform(0.1, 0.35)),
                     label=int(rng.integers(0, 4)), planar=planar) for _ in range(int(rng.integers(1, 4)))]
    ang = rng.uniform(-1.2, 1.2)  # a wall not aligned with a grid axis (module docstring)
    normal = (math.sin(ang), math.cos(ang), 0.0)
    shapes.append(Plane.through((0.0, -0.8, 0.0), normal, label=int(rng.integers(0, 4))))
    z = (0.0, 0.0) if planar else (-0.5, 0.5)
    voxel = float(rng.choice([0.05, 0.08]))
    grid = to_esdf(AnalyticField(shapes, groups=GROUPS), [-0.6, -1.0, z[0]], [2.0, 1.0, z[1]], voxel, planar=planar)
    return grid.with_interpolation(interpolation)  # type: ignore[arg-type]


def random_config(rng: np.random.Generator, model: str) -> FilterConfig:
    kw: dict = {"interpolation": INTERPOLATIONS[int(rng.integers(0, 4))],
                "predictive_rows": bool(rng.random() < 0.8), "margins_in_filter": bool(rng.random() < 0.3),
                "slack": bool(rng.random() < 0.8)}
    kw["map_margin_voxels"] = float(rng.choice([0.0, 0.5, 1.0]))
    if model == "double3d":
        kw["barrier"] = "hocbf" if rng.random() < 0.4 else "braking"
        kw["brake_speed_floor"] = float(rng.choice([1e-3, 0.1, 0.3]))
        kw["brake_rate_length"] = float(rng.choice([0.02, 0.2, np.inf]))
        if rng.random() < 0.3:
            kw["footprint"] = Footprint(shape="none")
    else:
        shape = ["rectangle", "capsule", "sphere", "none", None][int(rng.integers(0, 5))]
        if shape is not None:
            kw["footprint"] = Footprint(shape=shape, discs=int(rng.integers(1, 5)))  # type: ignore[arg-type]
    if rng.random() < 0.3:
        kw["extra_points"] = [tuple(rng.uniform(-0.2, 0.2, 3))]
    return FilterConfig(model=model, **kw)  # type: ignore[arg-type]


def random_state(rng: np.random.Generator, planar: bool) -> FilterState:
    # Mostly inside the map near the obstacles; a few past its border (outside_map).
    p = rng.uniform([-0.8, -1.1, -0.5], [2.2, 1.1, 0.5])
    v = tuple(rng.normal(0, 0.6, 3))
    if planar:
        return FilterState.planar(p[0], p[1], rng.uniform(-math.pi, math.pi), velocity=v)
    return FilterState(p, so3_exp(rng.normal(0, 0.5, 3)), np.array(v))


def assert_same(a, b) -> None:
    assert a.fallback == b.fallback
    assert a.risk_group == b.risk_group
    assert a.intervening == b.intervening
    assert a.rows == b.rows
    assert a.solver == b.solver
    assert a.h == pytest.approx(b.h, abs=1e-9)
    assert a.margin == pytest.approx(b.margin, abs=1e-9)
    np.testing.assert_allclose(a.u, b.u, atol=1e-9, rtol=0)
    np.testing.assert_array_equal(a.u_ref, b.u_ref)


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_compiled_step_equals_the_numpy_step(model, seed):
    rng = np.random.default_rng(seed)
    planar = model in ("unicycle", "single2d")
    field = random_field(rng, planar, "trilinear")
    fast = SafetyFilter(random_config(np.random.default_rng(int(rng.integers(0, 2**31))), model))
    slow = ReferenceFilter(fast)
    lo, hi = fast.model.lo, fast.model.hi
    for _ in range(25):
        s = random_state(rng, planar)
        u_ref = rng.uniform(1.3 * lo, 1.3 * hi)  # also beyond the box
        ang = rng.normal(0, 1.0, 3)
        assert_same(fast.filter(s, u_ref, field, ang), slow.filter(s, u_ref, field, ang))


def outcomes_alike(model: str, field, rng: np.random.Generator, steps: int) -> set:
    """The default filter's step and its oracle on ``steps`` random states and references: the
    same result each time; returns the outcomes seen (``intervening``, None or a fallback)."""
    planar = model in ("unicycle", "single2d")
    fast = SafetyFilter(FilterConfig(model=model))  # type: ignore[arg-type]
    slow = ReferenceFilter(fast)
    seen = set()
    for _ in range(steps):
        s = random_state(rng, planar)
        u_ref = rng.uniform(fast.model.lo, fast.model.hi)
        a, b = fast.filter(s, u_ref, field), slow.filter(s, u_ref, field)
        assert_same(a, b)
        seen.add("intervening" if a.intervening and a.fallback is None else a.fallback)
    return seen


@pytest.mark.parametrize("model", MODELS)
def test_the_compiled_step_intervenes_and_relaxes_like_the_numpy_step(model):
    # Not vacuous: the random cases above include interventions, slack steps and brakes.
    rng = np.random.default_rng(7)
    field = random_field(rng, model in ("unicycle", "single2d"), "bspline_smooth")
    seen = outcomes_alike(model, field, rng, 400)
    assert {"intervening", None, "outside_map"} <= seen, seen


def test_bad_inputs_brake_the_same_way():
    field = random_field(np.random.default_rng(1), True, "bspline_smooth")
    fast = SafetyFilter(FilterConfig())
    slow = ReferenceFilter(fast)
    s = FilterState.planar(0.0, 0.0, 0.3)
    for u_ref, ang in [((math.nan, 0.0), None), ((0.5, 0.0), (0.0, 0.0, math.inf)), ((0.5,), None)]:
        a = fast.filter(s, np.array(u_ref), field, None if ang is None else np.array(ang))
        b = slow.filter(s, np.array(u_ref), field, None if ang is None else np.array(ang))
        assert a.fallback == b.fallback == "non_finite"
        np.testing.assert_array_equal(a.u, b.u)
    # A non-finite state brakes before the field is read, on any field.
    bad = FilterState(np.array([math.nan, 0.0, 0.0]))
    analytic = AnalyticField(Sphere((1.0, 0.0, 0.0), 0.3, label=1, planar=True), groups=GROUPS)
    for f in (field, analytic):
        res = fast.filter(bad, np.array([0.5, 0.0]), f)
        assert res.fallback == "non_finite" and res.solver == ""
        np.testing.assert_array_equal(res.u, fast.model.brake(bad))


@pytest.mark.parametrize("model", MODELS)
def test_compiled_step_agrees_with_osqp(model):
    rng = np.random.default_rng(3)
    planar = model in ("unicycle", "single2d")
    field = random_field(rng, planar, "bspline_smooth")
    fast = SafetyFilter(FilterConfig(model=model))  # type: ignore[arg-type]
    osqp = ReferenceFilter(fast, solver="osqp")
    compared = 0
    for _ in range(300):
        s = random_state(rng, planar)
        u_ref = rng.uniform(fast.model.lo, fast.model.hi)
        a, b = fast.filter(s, u_ref, field), osqp.filter(s, u_ref, field)
        if a.fallback is None and b.fallback is None and a.intervening:
            np.testing.assert_allclose(a.u, b.u, atol=2e-4 * (1 + np.abs(fast.model.hi).max()))
            compared += 1
    assert compared > 10


def test_without_numba_the_filter_names_what_to_install(monkeypatch):
    monkeypatch.setattr(compiled, "HAVE_NUMBA", False)  # an install without numba
    with pytest.raises(ModuleNotFoundError) as info:
        SafetyFilter(FilterConfig())
    assert info.value.name == "numba"


@pytest.mark.parametrize("model", MODELS)
def test_analytic_fields_are_queried_by_the_caller_and_stepped_alike(model):
    """A field without a compiled query (analytic, point cloud) is read by its own ``query`` between
    the two kernels; the rest of the step is the same code."""
    rng = np.random.default_rng(13)
    planar = model in ("unicycle", "single2d")
    shapes = [Sphere(tuple(rng.uniform([0.4, -0.4, -0.1], [1.2, 0.4, 0.1])), 0.25, label=1, planar=planar),
              Plane.through((0.0, -0.8, 0.0), (math.sin(0.3), math.cos(0.3), 0.0), label=2)]
    field = AnalyticField(shapes, groups=GROUPS)
    SafetyFilter(FilterConfig(model=model))  # type: ignore[arg-type]
    before = len(compiled.points_kernel.signatures)
    seen = outcomes_alike(model, field, rng, 200)
    assert "intervening" in seen, seen
    assert len(compiled.points_kernel.signatures) == before  # loaded at construction


def test_no_compilation_in_the_control_loop():
    """One machine-code specialisation serves every map: float32 grids from ``to_esdf`` and the
    read-only arrays of a decoded ``EsdfGrid`` message alike (converted once per map)."""
    filt = SafetyFilter(FilterConfig())
    before = len(compiled.step_kernel.signatures)
    assert before >= 1  # compiled at construction
    rng = np.random.default_rng(5)
    local = random_field(rng, True, "trilinear")
    wire = EsdfField.from_grid(decode(encode(to_grid_message(local)), EsdfGrid), "bspline_smooth")
    for field in (local, wire, local.with_interpolation("bspline")):
        for _ in range(5):
            filt.filter(random_state(rng, True), np.array([0.5, 0.5]), field)
    assert len(compiled.step_kernel.signatures) == before


def toy_model() -> BarrierModel:
    """A model the filter has not heard of, in one description: an omnidirectional base that
    drives x, y and turns (three inputs, one of them angular), nothing passed through, with a
    triangular footprint of three unequal discs off the body's axis."""
    return BarrierModel(ModelSpec(
        "toy_omni", order=1, attitude="yaw", lin=[[1, 0, 0], [0, 1, 0], [0, 0, 0]],
        ang=[[0, 0, 0], [0, 0, 0], [0, 0, 1]],
        passthrough=(0.0, 0.0, 0.0), offsets=[(0.2, 0.0, 0.0), (-0.1, 0.12, 0.0), (-0.1, -0.12, 0.0)],
        radii=[0.08, 0.12, 0.1], weights=[1.0, 2.0, 0.3], lo=[-0.8, -0.5, -1.5], hi=[0.8, 0.5, 1.5]))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_a_new_model_is_one_description_and_the_oracle_agrees(seed):
    rng = np.random.default_rng(seed)
    field = random_field(rng, True, "trilinear")
    fast = SafetyFilter(random_config(np.random.default_rng(int(rng.integers(0, 2**31))), "unicycle"),
                        model=toy_model())
    slow = ReferenceFilter(fast)
    assert fast.model.m == 3
    for _ in range(25):
        s = random_state(rng, True)
        u_ref = rng.uniform(1.3 * fast.model.lo, 1.3 * fast.model.hi)
        assert_same(fast.filter(s, u_ref, field), slow.filter(s, u_ref, field))


def test_the_new_model_intervenes_and_its_rows_are_its_barrier_rates():
    """Not vacuous: the toy filter intervenes, and each row is ḣ_i(u) + α h_i by differences of the
    exact motion (so the step and its oracle agree on the right thing)."""
    rng = np.random.default_rng(11)
    field = random_field(rng, True, "bspline_smooth")
    filt = SafetyFilter(FilterConfig(), model=toy_model())
    seen = set()
    for _ in range(300):
        s = random_state(rng, True)
        res = filt.filter(s, rng.uniform(filt.model.lo, filt.model.hi), field)
        seen.add("intervening" if res.intervening and res.fallback is None else res.fallback)
    assert {"intervening", None} <= seen, seen
    model = filt.model
    s = FilterState.planar(0.2, 0.1, 0.7)
    u = np.array([0.5, -0.3, 1.0])
    sample = field.query(model.points(s))
    h = sample.distance - model.radius
    a, b = model.rows(s, sample, h, np.array([[1.0, 1.0, 1.0, 0.0]] * model.m), np.zeros(3))
    eps = 1e-6
    rate = (model.h(model.integrate(s, u, eps), field) - model.h(model.integrate(s, u, -eps), field)) / (2 * eps)
    np.testing.assert_allclose(a @ u - b, rate + h, atol=1e-5)
