"""Point queries as ``map/esdf/query`` answers them: trilinear distance, finite-difference gradient,
nearest risk group, the one in-map rule — and the query service agreeing with the filter on it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import DistanceQuery, EsdfGrid
from riskfield.services.fields import EsdfField, answer_query
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.mapper import Mapper
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.state import FilterState

ORIGIN = np.array([-1.0, 2.0, 0.5])
V = 0.1


def linear_field(shape: tuple[int, int, int], a: np.ndarray, b: float) -> EsdfField:
    idx = np.indices(shape).transpose(1, 2, 3, 0)
    pos = ORIGIN + V * idx
    dist = (pos @ a + b).astype(np.float32)
    groups = (idx[..., 0] % 3 + 1).astype(np.uint8)
    return EsdfField(dist, ORIGIN, V, groups, ["high", "mid", "low"], max_distance=10.0)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(*[st.floats(0, 1)] * 3), min_size=1, max_size=30))
def test_linear_fields_are_reproduced_exactly(fracs: list) -> None:
    shape = (7, 6, 5)
    a, b = np.array([0.3, -0.7, 0.2]), 0.4
    f = linear_field(shape, a, b)
    p = ORIGIN + np.array(fracs) * V * (np.array(shape) - 1)
    ans = answer_query(f, p)
    assert ans.inside.all()
    assert np.allclose(ans.distance, p @ a + b, atol=1e-5)
    assert np.allclose(ans.gradient, a, atol=1e-4)


def test_risk_group_is_the_nearest_voxels() -> None:
    f = linear_field((7, 6, 5), np.array([1.0, 0, 0]), 0.0)
    p = ORIGIN + np.array([[0.04, 0, 0], [0.06, 0, 0], [0.26, 0.1, 0.1]])
    assert answer_query(f, p).risk_group.tolist() == [1, 2, 1]


@pytest.mark.parametrize("unknown", [False, True])
def test_outside_the_hull_of_voxel_centres_is_not_in_the_map(unknown: bool) -> None:
    f = EsdfField(np.zeros((4, 4, 4), np.float32), ORIGIN, V, np.ones((4, 4, 4), np.uint8), ["g"], 2.0, unknown)
    # The hull of centres is [0, 0.3] per axis; the outer voxels' cubes reach −0.05 and 0.35.
    p = ORIGIN + np.array([[0.0, 0, 0], [-0.001, 0, 0], [-0.049, 0, 0], [0.3, 0.3, 0.3], [0.301, 0, 0],
                           [0.349, 0.1, 0.1], [0, 0, 1.0]])
    ans = answer_query(f, p)
    assert ans.inside.tolist() == [True, False, False, True, False, False, False]
    assert np.all(ans.distance[~ans.inside] == (-2.0 if unknown else 2.0))
    assert np.all(ans.gradient[~ans.inside] == 0) and np.all(ans.risk_group[~ans.inside] == 0)
    assert np.all(ans.risk_group[ans.inside] == 1)


def test_a_slice_ignores_z_and_has_no_z_gradient() -> None:
    idx = np.indices((6, 5, 1)).transpose(1, 2, 3, 0)
    dist = (0.5 * idx[..., 0] * V - 0.25 * idx[..., 1] * V).astype(np.float32)
    f = EsdfField(dist, ORIGIN, V, np.ones(dist.shape, np.uint8), ["g"], 5.0)
    p = np.array([[ORIGIN[0] + 0.23, ORIGIN[1] + 0.17, z] for z in (-3.0, 0.0, 7.0)])
    ans = answer_query(f, p)
    assert ans.inside.all()
    assert np.allclose(ans.distance, 0.5 * 0.23 - 0.25 * 0.17, atol=1e-6)
    assert np.allclose(ans.gradient, [[0.5, -0.25, 0.0]] * 3, atol=1e-5)


def _grid(shape: tuple[int, int, int]) -> EsdfGrid:
    # Far from any obstacle, so the filter passes the reference wherever it is in the map.
    dist = np.full(shape, 1.5, np.float32)
    return EsdfGrid(origin=tuple(ORIGIN), voxel_size=V, distance=dist, risk_group=np.ones(shape, np.uint8),
                    groups=["high", "mid", "low"], max_distance=2.0, unknown_is_occupied=False)


@pytest.mark.parametrize("shape", [(8, 7, 6), (8, 7, 1)], ids=["3d", "slice"])
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_the_query_service_and_the_filter_agree_near_the_border(shape: tuple[int, int, int], seed: int) -> None:
    """Where the mapper's query answer says in_map, the filter acts on the field; elsewhere it
    brakes with ``outside_map`` — for points within a voxel of the border, on both sides."""
    grid = _grid(shape)
    mapper = Mapper(MapperConfig(voxel_size=V, max_distance=2.0))
    mapper.output.field = EsdfField.from_grid(grid)  # what update_esdf leaves for the query service
    filt = SafetyFilter(FilterConfig(model="single3d"))
    field = EsdfField.from_grid(grid)  # what the filter node builds from the published grid
    rng = np.random.default_rng(seed)
    upper = ORIGIN + V * (np.array(shape) - 1)
    # On a border face (or just across it) along a random axis, anywhere along the others.
    p = rng.uniform(ORIGIN - V, upper + V, (40, 3))
    axis = rng.integers(0, 3, 40)
    side = np.where(rng.random(40) < 0.5, ORIGIN[axis], upper[axis])
    p[np.arange(40), axis] = side + rng.choice([-1, 1], 40) * rng.choice([0.0, 1e-12, 1e-6, 0.02, 0.049, 0.051], 40)
    reply = mapper.query(DistanceQuery(points=p).points)
    for k in range(len(p)):
        res = filt.filter(FilterState(p[k]), np.array([0.1, 0.0, 0.0]), field)
        assert (res.fallback == "outside_map") == (not reply.inside[k]), (p[k], res.fallback, reply.inside[k])
        assert filt.barrier(FilterState(p[k]), field)[2] == bool(reply.inside[k])
    assert reply.inside.any() and not reply.inside.all()
