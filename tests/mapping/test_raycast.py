"""Voxel traversal: connected, complete and exact against dense sampling of the segment."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.mapping.raycast import ray_voxels_py

SHAPE = (12, 9, 7)
f = st.floats(-3, 14, allow_nan=False)


@settings(max_examples=150, deadline=None)
@given(st.tuples(f, f, f), st.tuples(f, f, f))
def test_traversal_matches_dense_sampling(a: tuple, b: tuple) -> None:
    a, b = np.array(a), np.array(b)
    length = np.linalg.norm(b - a)
    if length < 1e-3:
        return
    d = (b - a) / length
    got = ray_voxels_py(a, d, 0.0, length, SHAPE)
    # dense samples of the segment inside the grid (its open interior: an end point exactly on
    # a voxel face touches the next voxel only in that point)
    t = np.linspace(1e-6 * length, (1 - 1e-6) * length, 4000)
    p = a + t[:, None] * d
    idx = np.floor(p + 0.5).astype(int)
    inside = np.all((idx >= 0) & (idx < np.array(SHAPE)), axis=1)
    sampled = {tuple(i) for i in idx[inside]}
    visited = [tuple(int(x) for x in v) for v in got]
    assert len(set(visited)) == len(visited), "a voxel is visited twice"
    assert sampled <= set(visited), "the traversal skipped a voxel the segment crosses"
    # consecutive voxels are face neighbours
    if len(got) > 1:
        steps = np.abs(np.diff(got, axis=0)).sum(axis=1)
        assert np.all(steps == 1)
    # every visited voxel is within reach of the segment (its cube touches the segment up to rounding)
    for v in got:
        c = np.asarray(v, dtype=float)
        tt = np.clip((c - a) @ d, 0, length)
        assert np.abs(a + tt * d - c).max() <= 0.5 + 1e-6 or np.linalg.norm(a + tt * d - c) <= np.sqrt(3) / 2 + 1e-6


def test_segment_outside_the_grid_visits_nothing() -> None:
    assert len(ray_voxels_py([-5, -5, -5], [0, 0, -1], 0, 10, SHAPE)) == 0
    assert len(ray_voxels_py([-5, 4, 3], [1, 0, 0], 0, 2, SHAPE)) == 0


def test_axis_ray_visits_the_expected_row() -> None:
    got = ray_voxels_py([-2.0, 4.0, 3.0], [1, 0, 0], 0, 100, SHAPE)
    assert got.tolist() == [[i, 4, 3] for i in range(SHAPE[0])]
