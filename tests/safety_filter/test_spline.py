"""Cubic ESDF interpolation (services/field_spline.py through EsdfField): exact for the
polynomials each kernel reproduces, derivatives that are its own, continuous across faces."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.field import kernel_weights
from riskfield.services.fields import EsdfField

H = 0.05
EYE = np.eye(3)


def grid_of(f, shape, planar: bool) -> np.ndarray:
    axes = [H * np.arange(n) for n in shape]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    return f(x, y, z)


def poly(coef: np.ndarray, degree: int):
    """Σ c_{ijk} x^i y^j z^k over i + j + k ≤ degree (coefficients in a fixed order)."""
    terms = [(i, j, k) for i in range(degree + 1) for j in range(degree + 1) for k in range(degree + 1)
             if i + j + k <= degree]

    def f(x, y, z):
        return sum(c * x**i * y**j * z**k for c, (i, j, k) in zip(coef, terms, strict=False))

    return f, len(terms)


def coefs(n: int):
    return st.lists(st.floats(-3, 3), min_size=n, max_size=n).map(np.array)


@pytest.mark.parametrize("kernel,degree", [("catmull_rom", 2), ("bspline", 3), ("bspline_smooth", 1)])
@pytest.mark.parametrize("planar", [False, True])
@settings(max_examples=12, deadline=None)
@given(data=st.data())
def test_reproduces_its_polynomials_with_their_derivatives(kernel, degree, planar, data):
    n_terms = poly(np.zeros(40), degree)[1]
    c = data.draw(coefs(n_terms))
    if planar:  # a 2-D slice ignores z: only the x, y terms
        f0, _ = poly(c, degree)
        f = lambda x, y, z: f0(x, y, 0 * z)  # noqa: E731
        shape = (40, 40, 1)
    else:
        f, _ = poly(c, degree)
        shape = (32, 32, 32)
    field = EsdfField(grid_of(f, shape, planar), [0, 0, 0], H, interpolation=kernel)
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31)))
    lo, hi = 12 * H, (min(shape[:2]) - 13) * H  # away from the border's mirror condition
    p = rng.uniform(lo, hi, (50, 3))
    if planar:
        p[:, 2] = 0.0
    s = field.query(p, hessian=True)
    scale = 1.0 + np.abs(c).sum()
    np.testing.assert_allclose(s.distance, f(*p.T), atol=2e-6 * scale)
    e = 1e-4
    grad = np.stack([(f(*(p + e * EYE[i]).T) - f(*(p - e * EYE[i]).T)) / (2 * e) for i in range(3)], axis=1)
    if planar:
        grad[:, 2] = 0.0
    np.testing.assert_allclose(s.gradient, grad, atol=5e-5 * scale)


def noisy_field(kernel: str, planar: bool, seed: int) -> EsdfField:
    rng = np.random.default_rng(seed)
    shape = (12, 12, 1) if planar else (10, 10, 10)
    return EsdfField(rng.normal(0.3, 0.1, shape), [0, 0, 0], H, interpolation=kernel)


@pytest.mark.parametrize("kernel", ["catmull_rom", "bspline", "bspline_smooth"])
@pytest.mark.parametrize("planar", [False, True])
@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_gradient_and_hessian_are_the_derivatives_of_the_distance(kernel, planar, seed):
    field = noisy_field(kernel, planar, seed)
    rng = np.random.default_rng(seed)
    p = rng.uniform(1.2 * H, 7.8 * H, (40, 3))
    s = field.query(p, hessian=True)
    e = 1e-6
    fd_g = np.stack([(field.query(p + e * EYE[i]).distance - field.query(p - e * EYE[i]).distance) / (2 * e)
                     for i in range(3)], axis=1)
    fd_h = np.stack([(field.query(p + e * EYE[i]).gradient - field.query(p - e * EYE[i]).gradient) / (2 * e)
                     for i in range(3)], axis=1)
    np.testing.assert_allclose(s.gradient, fd_g, atol=1e-5)
    frac = (p / H) % 1.0
    inner = ((frac > 1e-4) & (frac < 1 - 1e-4)).all(axis=1)  # Catmull-Rom's Hessian jumps at faces
    np.testing.assert_allclose(s.hessian[inner], fd_h[inner], atol=1e-3)  # O(1/h) on noise: 1e-3 is tight
    np.testing.assert_allclose(s.hessian, np.swapaxes(s.hessian, 1, 2), atol=1e-9)


def test_trilinear_gradient_is_not_its_own_derivative():
    """Why the kernels exist: the paper's field's gradient differs from the rate of its distance."""
    field = noisy_field("trilinear", False, 3)
    p = np.random.default_rng(0).uniform(1.2 * H, 7.8 * H, (40, 3))
    e = 1e-6
    fd = (field.query(p + e * EYE[0]).distance - field.query(p - e * EYE[0]).distance) / (2 * e)
    assert np.abs(field.query(p).gradient[:, 0] - fd).max() > 0.05


@pytest.mark.parametrize("kernel", ["catmull_rom", "bspline", "bspline_smooth"])
@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31), axis=st.integers(0, 2))
def test_gradient_is_continuous_across_cell_faces(kernel, seed, axis):
    field = noisy_field(kernel, False, seed)
    rng = np.random.default_rng(seed)
    p = rng.uniform(2 * H, 7 * H, (30, 3))
    p[:, axis] = H * rng.integers(2, 8, 30)  # on a face between two cells
    e = 1e-9
    below, above = field.query(p - e * EYE[axis], hessian=True), field.query(p + e * EYE[axis], hessian=True)
    np.testing.assert_allclose(below.distance, above.distance, atol=1e-7)
    np.testing.assert_allclose(below.gradient, above.gradient, atol=1e-5)
    jump = np.abs(below.hessian - above.hessian).max()
    if kernel != "catmull_rom":
        assert jump < 1e-3  # C²: the Hessian is continuous too
    else:
        assert np.isfinite(jump)  # Catmull-Rom is C¹ only: its Hessian may jump here


def test_weights_are_a_partition_of_unity_with_zero_sum_derivatives():
    t = np.random.default_rng(1).uniform(0, 1, (100, 3))
    for kernel in ("catmull_rom", "bspline", "bspline_smooth"):
        w = kernel_weights(t, H, kernel, 3)  # type: ignore[arg-type]
        np.testing.assert_allclose(w[:, :, 0].sum(axis=-1), 1.0)
        np.testing.assert_allclose(w[:, :, 1:].sum(axis=-1), 0.0, atol=1e-9)


def test_unknown_interpolation_is_a_clear_error():
    with pytest.raises(ValueError, match="interpolation"):
        EsdfField(np.zeros((4, 4, 1)), [0, 0, 0], H, interpolation="quintic")  # type: ignore[arg-type]


def test_the_smoothing_bspline_is_close_to_a_sphere_and_conservative_at_a_ridge():
    """It never reads more than a few mm (h²/6 ∂²d) above the geometry, and at the ridge between
    two obstacles (a concave kink) it reads less than the true distance — where the interpolating
    kernels overshoot (why it is the filter's default)."""
    from riskfield.services.fields import AnalyticField, to_esdf
    from riskfield.services.geometry.shapes import Sphere

    truth = AnalyticField([Sphere((0.0, 0.0, 0.0), 0.3), Sphere((1.0, 0.0, 0.0), 0.3)])
    grid = to_esdf(truth, [-0.8, -0.8, -0.8], [1.8, 0.8, 0.8], H).with_interpolation("bspline_smooth")
    rng = np.random.default_rng(0)
    p = rng.uniform([-0.6, -0.6, -0.6], [1.6, 0.6, 0.6], (2000, 3))
    p = p[truth.query(p).distance > 0.0]
    assert (grid.query(p).distance - truth.query(p).distance).max() < 0.004
    ridge = np.stack([np.full(200, 0.5), rng.uniform(-0.3, 0.3, 200), rng.uniform(-0.3, 0.3, 200)], axis=1)
    assert np.all(grid.query(ridge).distance < truth.query(ridge).distance)
    band = ridge + np.array([1.0, 0.0, 0.0]) * rng.uniform(-0.03, 0.03, (200, 1))
    assert (grid.query(band).distance - truth.query(band).distance).max() < 0.004
    overshoot = grid.with_interpolation("catmull_rom").query(band).distance - truth.query(band).distance
    assert overshoot.max() > 0.004
