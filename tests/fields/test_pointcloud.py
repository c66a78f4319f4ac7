"""The point-cloud baseline field: nearest-point distance, its derivatives, voxel downsampling."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.fields import PointCloudField


def sphere_points(n: int, c: np.ndarray, r: float, seed: int = 0) -> np.ndarray:
    x = np.random.default_rng(seed).normal(size=(n, 3))
    return c + r * x / np.linalg.norm(x, axis=1, keepdims=True)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=3, max_size=3))
def test_pointcloud_distance_matches_brute_force_and_gradient_is_unit(q):
    pts = sphere_points(500, np.zeros(3), 0.5)
    f = PointCloudField(voxel_size=1e-4)
    f.integrate(pts)
    s = f.query(np.array([q]), hessian=True)
    brute = np.linalg.norm(pts - np.array(q), axis=1).min()
    assert s.distance[0] == pytest.approx(min(max(brute, f.min_distance), f.far))
    assert np.linalg.norm(s.gradient[0]) == pytest.approx(1.0)
    # Hessian of the distance to a point: symmetric, the gradient is in its null space.
    np.testing.assert_allclose(s.hessian[0], s.hessian[0].T, atol=1e-12)
    np.testing.assert_allclose(s.hessian[0] @ s.gradient[0], 0.0, atol=1e-9)


def test_pointcloud_gradient_matches_finite_differences_away_from_switches():
    f = PointCloudField(voxel_size=1e-4)
    f.integrate(np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]))
    p, h = np.array([0.4, 0.3, 0.2]), 1e-6
    s = f.query(p[None], hessian=True)
    fd = [(f.query((p + h * e)[None]).distance[0] - f.query((p - h * e)[None]).distance[0]) / (2 * h)
          for e in np.eye(3)]
    np.testing.assert_allclose(s.gradient[0], fd, atol=1e-6)


def test_pointcloud_voxel_downsampling_and_empty_field():
    f = PointCloudField(voxel_size=0.1)
    assert f.query(np.zeros((2, 3))).distance.tolist() == [f.far, f.far]
    f.integrate(np.array([[0.01, 0.01, 0.01], [0.02, 0.02, 0.02], [0.5, 0.5, 0.5], [np.nan, 0, 0]]))
    assert f.size == 2  # two points share a voxel, NaN dropped
    f.integrate(np.array([[0.03, 0.03, 0.03]]))
    assert f.size == 2
