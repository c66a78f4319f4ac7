"""The compiled filter step (``safety_filter.compiled``) against the numpy step and OSQP.

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


def random_config(rng: np.random.Generator, model: str, backend: str) -> FilterConfig:
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
    return FilterConfig(model=model, backend=backend, **kw)  # type: ignore[arg-type]


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
    cfg_seed = int(rng.integers(0, 2**31))
    fast = SafetyFilter(random_config(np.random.default_rng(cfg_seed), model, "numba"))
    slow = SafetyFilter(random_config(np.random.default_rng(cfg_seed), model, "numpy"))
    assert fast.backend == "numba" and slow.backend == "numpy"
    lo, hi = fast.model.lo, fast.model.hi
    for _ in range(25):
        s = random_state(rng, planar)
        u_ref = rng.uniform(1.3 * lo, 1.3 * hi)  # also beyond the box
        ang = rng.normal(0, 1.0, 3)
        assert_same(fast.filter(s, u_ref, field, ang), slow.filter(s, u_ref, field, ang))


@pytest.mark.parametrize("model", MODELS)
def test_the_compiled_step_intervenes_and_relaxes_like_the_numpy_step(model):
    # Not vacuous: the random cases above include interventions, slack steps and brakes.
    rng = np.random.default_rng(7)
    planar = model in ("unicycle", "single2d")
    field = random_field(rng, planar, "bspline_smooth")
    fast = SafetyFilter(FilterConfig(model=model))  # type: ignore[arg-type]
    slow = SafetyFilter(FilterConfig(model=model, backend="numpy"))  # type: ignore[arg-type]
    seen = set()
    for _ in range(400):
        s = random_state(rng, planar)
        u_ref = rng.uniform(fast.model.lo, fast.model.hi)
        a, b = fast.filter(s, u_ref, field), slow.filter(s, u_ref, field)
        assert_same(a, b)
        seen.add("intervening" if a.intervening and a.fallback is None else a.fallback)
    assert {"intervening", None, "outside_map"} <= seen, seen


def test_bad_inputs_brake_the_same_way():
    field = random_field(np.random.default_rng(1), True, "bspline_smooth")
    fast, slow = SafetyFilter(FilterConfig()), SafetyFilter(FilterConfig(backend="numpy"))
    s = FilterState.planar(0.0, 0.0, 0.3)
    for u_ref, ang in [((math.nan, 0.0), None), ((0.5, 0.0), (0.0, 0.0, math.inf)), ((0.5,), None)]:
        a = fast.filter(s, np.array(u_ref), field, None if ang is None else np.array(ang))
        b = slow.filter(s, np.array(u_ref), field, None if ang is None else np.array(ang))
        assert a.fallback == b.fallback == "non_finite"
        np.testing.assert_array_equal(a.u, b.u)
    # A non-finite state is handed back to the numpy path: the same answer by construction.
    bad = FilterState(np.array([math.nan, 0.0, 0.0]))
    with np.errstate(invalid="ignore"):  # the grid query casts the NaN point (and flags it outside)
        a, b = fast.filter(bad, np.array([0.5, 0.0]), field), slow.filter(bad, np.array([0.5, 0.0]), field)
    assert a.fallback == b.fallback and a.fallback is not None


@pytest.mark.parametrize("model", MODELS)
def test_compiled_step_agrees_with_osqp(model):
    rng = np.random.default_rng(3)
    planar = model in ("unicycle", "single2d")
    field = random_field(rng, planar, "bspline_smooth")
    fast = SafetyFilter(FilterConfig(model=model))  # type: ignore[arg-type]
    osqp = SafetyFilter(FilterConfig(model=model, solver="osqp"))  # type: ignore[arg-type]
    assert fast.backend == "numba" and osqp.backend == "numpy"
    compared = 0
    for _ in range(300):
        s = random_state(rng, planar)
        u_ref = rng.uniform(fast.model.lo, fast.model.hi)
        a, b = fast.filter(s, u_ref, field), osqp.filter(s, u_ref, field)
        if a.fallback is None and b.fallback is None and a.intervening:
            np.testing.assert_allclose(a.u, b.u, atol=2e-4 * (1 + np.abs(fast.model.hi).max()))
            compared += 1
    assert compared > 10


def test_backend_selection(monkeypatch):
    assert SafetyFilter(FilterConfig()).backend == "numba"
    assert SafetyFilter(FilterConfig(backend="numpy")).backend == "numpy"
    assert SafetyFilter(FilterConfig(solver="osqp")).backend == "numpy"
    with pytest.raises(ValueError, match="active-set"):
        SafetyFilter(FilterConfig(solver="osqp", backend="numba"))
    monkeypatch.setattr(compiled, "HAVE_NUMBA", False)  # an install without numba
    assert SafetyFilter(FilterConfig()).backend == "numpy"
    with pytest.raises(ValueError, match="numba"):
        SafetyFilter(FilterConfig(backend="numba"))


def test_analytic_fields_take_the_numpy_path():
    field = AnalyticField(Sphere((1.0, 0.0, 0.0), 0.3, label=1, planar=True), groups=GROUPS)
    fast, slow = SafetyFilter(FilterConfig()), SafetyFilter(FilterConfig(backend="numpy"))
    s = FilterState.planar(0.3, 0.0, 0.0)
    a, b = fast.filter(s, np.array([1.0, 0.0]), field), slow.filter(s, np.array([1.0, 0.0]), field)
    assert a.intervening and a.qp_us > 0  # measured apart: the numpy path ran
    assert_same(a, b)


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
    """A model neither backend has heard of, in one description: an omnidirectional base that
    drives x, y and turns (three inputs, one of them angular), nothing passed through, with a
    triangular footprint of three unequal discs off the body's axis."""
    return BarrierModel(ModelSpec(
        "toy_omni", order=1, attitude="yaw", lin=[[1, 0, 0], [0, 1, 0], [0, 0, 0]],
        ang=[[0, 0, 0], [0, 0, 0], [0, 0, 1]],
        passthrough=(0.0, 0.0, 0.0), offsets=[(0.2, 0.0, 0.0), (-0.1, 0.12, 0.0), (-0.1, -0.12, 0.0)],
        radii=[0.08, 0.12, 0.1], weights=[1.0, 2.0, 0.3], lo=[-0.8, -0.5, -1.5], hi=[0.8, 0.5, 1.5]))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_a_new_model_is_one_description_and_both_backends_agree(seed):
    rng = np.random.default_rng(seed)
    field = random_field(rng, True, "trilinear")
    cfg_seed = int(rng.integers(0, 2**31))
    cfgs = [random_config(np.random.default_rng(cfg_seed), "unicycle", b) for b in ("numba", "numpy")]
    fast, slow = (SafetyFilter(c, model=toy_model()) for c in cfgs)
    assert fast.backend == "numba" and slow.backend == "numpy" and fast.model.m == 3
    for _ in range(25):
        s = random_state(rng, True)
        u_ref = rng.uniform(1.3 * fast.model.lo, 1.3 * fast.model.hi)
        assert_same(fast.filter(s, u_ref, field), slow.filter(s, u_ref, field))


def test_the_new_model_intervenes_and_its_rows_are_its_barrier_rates():
    """Not vacuous: the toy filter intervenes, and each row is ḣ_i(u) + α h_i by differences of the
    exact motion (so both backends agree on the right thing)."""
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
