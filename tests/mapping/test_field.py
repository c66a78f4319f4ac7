"""Point queries: trilinear distance, finite-difference gradient, nearest risk group, outside the map."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.mapping.field import DistanceField

ORIGIN = np.array([-1.0, 2.0, 0.5])
V = 0.1


def linear_field(shape: tuple[int, int, int], a: np.ndarray, b: float) -> DistanceField:
    idx = np.indices(shape).transpose(1, 2, 3, 0)
    pos = ORIGIN + V * idx
    dist = (pos @ a + b).astype(np.float32)
    groups = (idx[..., 0] % 3 + 1).astype(np.uint8)
    return DistanceField(dist, groups, ORIGIN, V, max_distance=10.0, unknown_is_occupied=False)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(*[st.floats(0, 1)] * 3), min_size=1, max_size=30))
def test_linear_fields_are_reproduced_exactly(fracs: list) -> None:
    shape = (7, 6, 5)
    a, b = np.array([0.3, -0.7, 0.2]), 0.4
    f = linear_field(shape, a, b)
    p = ORIGIN + np.array(fracs) * V * (np.array(shape) - 1)
    ans = f.query(p)
    assert ans.in_map.all()
    assert np.allclose(ans.distance, p @ a + b, atol=1e-5)
    assert np.allclose(ans.gradient, a, atol=1e-4)


def test_risk_group_is_the_nearest_voxels() -> None:
    f = linear_field((7, 6, 5), np.array([1.0, 0, 0]), 0.0)
    p = ORIGIN + np.array([[0.04, 0, 0], [0.06, 0, 0], [0.26, 0.1, 0.1]])
    assert f.query(p).risk_group.tolist() == [1, 2, 1]


@pytest.mark.parametrize("unknown", [False, True])
def test_outside_the_map(unknown: bool) -> None:
    f = DistanceField(np.zeros((4, 4, 4), np.float32), np.ones((4, 4, 4), np.uint8), ORIGIN, V, 2.0, unknown)
    p = ORIGIN + np.array([[-0.049, 0, 0], [-0.051, 0, 0], [0.349, 0.3, 0.3], [0.351, 0, 0], [0, 0, 1.0]])
    ans = f.query(p)
    assert ans.in_map.tolist() == [True, False, True, False, False]
    assert np.all(ans.distance[~ans.in_map] == (-2.0 if unknown else 2.0))
    assert np.all(ans.gradient[~ans.in_map] == 0) and np.all(ans.risk_group[~ans.in_map] == 0)


def test_a_slice_ignores_z_and_has_no_z_gradient() -> None:
    idx = np.indices((6, 5, 1)).transpose(1, 2, 3, 0)
    dist = (0.5 * idx[..., 0] * V - 0.25 * idx[..., 1] * V).astype(np.float32)
    f = DistanceField(dist, np.ones(dist.shape, np.uint8), ORIGIN, V, 5.0, False)
    p = np.array([[ORIGIN[0] + 0.23, ORIGIN[1] + 0.17, z] for z in (-3.0, 0.0, 7.0)])
    ans = f.query(p)
    assert ans.in_map.all()
    assert np.allclose(ans.distance, 0.5 * 0.23 - 0.25 * 0.17, atol=1e-6)
    assert np.allclose(ans.gradient, [[0.5, -0.25, 0.0]] * 3, atol=1e-5)
