"""EsdfField against closed-form fields: distance, gradient, Hessian, risk group, borders."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import EsdfGrid, decode, encode
from riskfield.services.fields import AnalyticField, EsdfField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Plane, Sphere

GROUPS = ["high", "mid", "low"]


def _points_between(field, rng, n, lo, hi, dmin, dmax, dims=3):
    p = rng.uniform(lo, hi, (20 * n, 3))
    if dims == 2:
        p[:, 2] = 0.0
    d = field.query(p).distance
    keep = p[(d > dmin) & (d < dmax)]
    assert len(keep) >= n
    return keep[:n]


def test_plane_is_reproduced_exactly_inside_the_grid():
    plane = AnalyticField(Plane.through([0.1, -0.2, 0.05], [1.0, 0.3, -0.2], label=2), groups=GROUPS)
    grid = to_esdf(plane, [-1, -1, -1], [1, 1, 1], 0.1, max_distance=10.0)
    rng = np.random.default_rng(0)
    p = rng.uniform(-1, 1, (500, 3))
    exact, got = plane.query(p, hessian=True), grid.query(p, hessian=True)
    assert got.inside.all()
    # A linear field is interpolated exactly, and its differences are exact (float32 storage aside).
    np.testing.assert_allclose(got.distance, exact.distance, atol=1e-6)
    np.testing.assert_allclose(got.gradient, exact.gradient, atol=1e-5)
    np.testing.assert_allclose(got.hessian, 0.0, atol=1e-3)
    assert (got.risk_group == 2).all()


def test_sphere_distance_gradient_hessian_match_closed_form():
    sphere = AnalyticField(Sphere([0.1, 0.0, -0.1], 0.5, label=1), groups=GROUPS)
    h = 0.05
    grid = to_esdf(sphere, [-2, -2, -2], [2, 2, 2], h)
    rng = np.random.default_rng(1)
    p = _points_between(sphere, rng, 400, -1.5, 1.5, 0.15, 1.2)
    exact, got = sphere.query(p, hessian=True), grid.query(p, hessian=True)
    # Interpolation error of a field with curvature 1/ρ is O(h²/ρ); differences O(h²/ρ²).
    np.testing.assert_allclose(got.distance, exact.distance, atol=2e-3)
    np.testing.assert_allclose(got.gradient, exact.gradient, atol=5e-3)
    np.testing.assert_allclose(got.hessian, exact.hessian, atol=2e-2)
    # The gradient of a distance field has unit length away from ridges.
    np.testing.assert_allclose(np.linalg.norm(got.gradient, axis=1), 1.0, atol=5e-3)
    assert (got.risk_group == 1).all()


def test_two_spheres_in_different_groups_report_the_nearest_group():
    field = AnalyticField([Sphere([-0.6, 0, 0], 0.3, label=1), Sphere([0.7, 0, 0], 0.3, label=3)], groups=GROUPS)
    grid = to_esdf(field, [-2, -1.5, -1], [2, 1.5, 1], 0.05)
    near_high = np.array([[-0.6, 0.45, 0.0], [-1.1, 0.0, 0.2]])
    near_low = np.array([[0.7, -0.5, 0.0], [1.2, 0.1, -0.1]])
    assert list(grid.query(near_high).risk_group) == [1, 1]
    assert list(grid.query(near_low).risk_group) == [3, 3]
    rng = np.random.default_rng(2)
    p = _points_between(field, rng, 300, [-1.9, -1.4, -0.9], [1.9, 1.4, 0.9], 0.1, 0.9)
    exact, got = field.query(p, hessian=True), grid.query(p, hessian=True)
    # Away from the ridge between the spheres (x = 0.05) the union is smooth.
    smooth = np.abs(p[:, 0] - 0.05) > 0.15
    np.testing.assert_allclose(got.distance, exact.distance, atol=3e-3)
    np.testing.assert_allclose(got.gradient[smooth], exact.gradient[smooth], atol=1e-2)
    np.testing.assert_allclose(got.hessian[smooth], exact.hessian[smooth], atol=5e-2)
    assert (got.risk_group[smooth] == exact.risk_group[smooth]).all()


def test_two_d_slice_is_bilinear_and_extruded_along_z():
    disc = AnalyticField(Sphere([0.2, -0.1, 0.0], 0.4, planar=True, label=3), groups=GROUPS)
    grid = to_esdf(disc, [-2, -2, 0], [2, 2, 0], 0.05, planar=True)
    assert grid.shape[2] == 1 and grid.planar
    rng = np.random.default_rng(3)
    p = _points_between(disc, rng, 300, -1.5, 1.5, 0.15, 1.0, dims=2)
    p[:, 2] = rng.uniform(-5, 5, len(p))  # any height: a slice is extruded
    exact, got = disc.query(p, hessian=True), grid.query(p, hessian=True)
    assert got.inside.all()
    np.testing.assert_allclose(got.distance, exact.distance, atol=2e-3)
    np.testing.assert_allclose(got.gradient, exact.gradient, atol=5e-3)
    assert (got.gradient[:, 2] == 0).all() and (got.hessian[:, 2, :] == 0).all()
    np.testing.assert_allclose(got.hessian, exact.hessian, atol=2e-2)


def test_outside_points_are_flagged_and_finite():
    grid = to_esdf(AnalyticField(Sphere([0, 0, 0], 0.3)), [-1, -1, -1], [1, 1, 1], 0.1)
    p = np.array([[0.5, 0.5, 0.5], [1.0, 1.0, 1.0], [1.01, 0, 0], [0, -1.2, 0], [0, 0, 7.0], [-1, -1, -1]])
    s = grid.query(p, hessian=True)
    assert list(s.inside) == [True, True, False, False, False, True]
    assert np.isfinite(s.distance).all() and np.isfinite(s.gradient).all() and np.isfinite(s.hessian).all()
    assert list(grid.inside(p)) == list(s.inside)


def test_gradient_at_the_border_is_one_sided_not_halved():
    plane = AnalyticField(Plane.through([0, 0, 0], [1, 0, 0]))
    grid = to_esdf(plane, [-1, -1, -1], [1, 1, 1], 0.1, max_distance=5)
    p = np.array([[-1.0, 0.0, 0.0], [1.0, 0.3, -1.0], [0.97, 0.99, 0.99]])
    np.testing.assert_allclose(grid.query(p).gradient, [[1, 0, 0]] * 3, atol=1e-5)


@settings(max_examples=60, deadline=None)
@given(
    origin=st.tuples(*[st.floats(-5, 5)] * 3),
    voxel=st.floats(0.02, 0.5),
    normal=st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda n: np.linalg.norm(n) > 0.1),
    frac=st.tuples(*[st.floats(0, 1)] * 3),
    planar=st.booleans(),
)
def test_linear_fields_are_exact_anywhere(origin, voxel, normal, frac, planar):
    n = np.array(normal)
    if planar:
        n[2] = 0.0
        if np.linalg.norm(n) < 0.1:
            n[0] = 1.0
    shape = np.array([5, 4, 1 if planar else 3])
    plane = AnalyticField(Plane.through(origin, n, label=1), groups=["a"])
    upper = np.array(origin) + voxel * (shape - 1)
    grid = to_esdf(plane, origin, upper + 1e-9, voxel, max_distance=1e6, planar=planar)
    assert grid.shape == tuple(shape)
    p = np.array(origin) + np.array(frac) * (upper - np.array(origin))
    got, exact = grid.query(p[None], hessian=True), plane.query(p[None])
    assert got.inside[0]
    tol = 1e-6 * (1 + np.abs(exact.distance[0])) + 1e-4 * voxel
    assert abs(got.distance[0] - exact.distance[0]) <= tol
    np.testing.assert_allclose(got.gradient[0], plane.shapes[0].normal, atol=1e-3)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), planar=st.booleans())
def test_gradient_and_hessian_are_central_differences_through_the_interpolant(seed, planar):
    rng = np.random.default_rng(seed)
    shape = (7, 6, 1 if planar else 5)
    grid = EsdfField(rng.normal(size=shape).astype(np.float32), rng.uniform(-1, 1, 3), 0.2)
    dims = 2 if planar else 3
    lo, hi = grid.origin + 0.2, grid.upper_corner() - 0.2
    if planar:
        lo[2], hi[2] = -3.0, 3.0  # any height
    p = rng.uniform(lo, hi)
    h = grid.voxel_size
    s = grid.query(p[None], hessian=True)
    d = lambda q: grid.query(np.asarray(q)[None]).distance[0]  # noqa: E731
    for a in range(dims):
        e = np.eye(3)[a] * h
        assert s.gradient[0, a] == pytest.approx((d(p + e) - d(p - e)) / (2 * h), abs=1e-9)
        assert s.hessian[0, a, a] == pytest.approx((d(p + e) - 2 * d(p) + d(p - e)) / h**2, abs=1e-7)
        for b in range(a + 1, dims):
            f = np.eye(3)[b] * h
            mixed = (d(p + e + f) - d(p + e - f) - d(p - e + f) + d(p - e - f)) / (4 * h * h)
            assert s.hessian[0, a, b] == pytest.approx(mixed, abs=1e-7)
            assert s.hessian[0, b, a] == s.hessian[0, a, b]


def test_from_grid_message_roundtrip_and_vectorised_equals_single():
    field = AnalyticField([Sphere([0, 0, 0], 0.3, label=1), Plane.through([0, -0.8, 0], [0, 1, 0], label=2)],
                          groups=GROUPS)
    esdf = to_esdf(field, [-1, -1, -0.5], [1, 1, 0.5], 0.1)
    msg = decode(encode(to_grid_message(esdf)), EsdfGrid)
    grid = EsdfField.from_grid(msg)
    rng = np.random.default_rng(4)
    p = rng.uniform(-1.1, 1.1, (50, 3))
    many = grid.query(p, hessian=True)
    for i in range(0, 50, 7):
        one = grid.query(p[i], hessian=True)
        assert one.distance[0] == pytest.approx(many.distance[i], abs=1e-12)
        np.testing.assert_allclose(one.gradient[0], many.gradient[i], atol=1e-12)
        np.testing.assert_allclose(one.hessian[0], many.hessian[i], atol=1e-9)
        assert one.risk_group[0] == many.risk_group[i] and one.inside[0] == many.inside[i]


@pytest.mark.parametrize("bad", [
    dict(distance=np.zeros((1, 4, 3))),
    dict(distance=np.zeros((4, 4))),
    dict(distance=np.full((3, 3, 3), np.nan)),
    dict(voxel_size=0.0),
    dict(origin=(np.inf, 0, 0)),
    dict(risk_group=np.full((3, 3, 3), 2, np.uint8)),
    dict(risk_group=np.zeros((3, 3, 2), np.uint8)),
])
def test_unusable_grids_are_rejected(bad):
    kw = dict(distance=np.ones((3, 3, 3), np.float32), origin=(0, 0, 0), voxel_size=0.1,
              risk_group=np.ones((3, 3, 3), np.uint8), groups=["a"])
    kw.update(bad)
    with pytest.raises(ValueError):
        EsdfField(**kw)
