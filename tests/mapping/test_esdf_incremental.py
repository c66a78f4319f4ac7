"""Incremental 3-D ESDF: after any sequence of edits it equals the full recompute (the oracle)."""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from oracles.esdf import FullEsdf
from riskfield.protocol import RiskConfig
from riskfield.services.geometry.shapes import Plane
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.esdf_integrator import EsdfIntegrator
from riskfield.services.mapping.mapper import Mapper

SHAPE = (40, 36, 30)
MARGINS = np.array([0.0, 0.15, 0.05, 0.0])

edit = st.tuples(
    st.integers(0, SHAPE[0] - 1), st.integers(0, SHAPE[1] - 1), st.integers(0, SHAPE[2] - 1),
    st.integers(1, 8), st.integers(1, 8), st.integers(1, 8), st.integers(0, 3),
)


def apply(groups: np.ndarray, e: tuple[int, ...]) -> None:
    i, j, k, a, b, c, g = e
    groups[i:i + a, j:j + b, k:k + c] = g  # g = 0 removes: obstacles shrink, split, open up inside


@settings(max_examples=25, deadline=None)
# A group split under dilation: the whole grid chose its base group by dilated sizes, a part by
# the grid's counts, and the two disagreed on ties (found by this test).
@example(start=[(0, 0, 0, 1, 1, 3, 1)], edits=[[(0, 0, 0, 1, 1, 2, 2)]], max_distance=0.2, inflation="dilate")
@given(start=st.lists(edit, min_size=0, max_size=6), edits=st.lists(st.lists(edit, min_size=1, max_size=3),
                                                                     min_size=1, max_size=4),
       max_distance=st.sampled_from([0.2, 0.35, 0.6]), inflation=st.sampled_from(["exact", "exact", "dilate"]))
def test_incremental_equals_full_recompute_on_random_edit_sequences(start: list, edits: list, max_distance: float,
                                                                    inflation: str) -> None:
    cfg = MapperConfig(max_distance=max_distance, inflation=inflation, threads=1)
    esdf = EsdfIntegrator.of(cfg)
    groups = np.zeros(SHAPE, np.uint8)
    for e in start:
        apply(groups, e)
    prev_groups = groups.copy()
    dist, grp = esdf.compute(groups, MARGINS)
    partial = 0
    for step in edits:
        groups = prev_groups.copy()
        for e in step:
            apply(groups, e)
        dist, grp, n = esdf.update(groups, MARGINS, prev_groups, (dist, grp))
        full_d, full_g = esdf.compute(groups, MARGINS)
        np.testing.assert_allclose(dist, full_d, atol=1e-5, rtol=0)
        np.testing.assert_array_equal(grp, full_g)
        partial += n < groups.size
        prev_groups = groups
    if max_distance == 0.2:
        assert partial > 0 or any(sum(e[3:6]) > 12 for s in edits for e in s)  # small reach: local work


def test_no_change_recomputes_nothing_and_a_local_edit_stays_local() -> None:
    cfg = MapperConfig(max_distance=0.2)
    esdf = EsdfIntegrator.of(cfg)
    groups = np.zeros((80, 80, 40), np.uint8)
    groups[10:20, 10:20, 0:10] = 3
    groups[60:70, 60:70, 0:10] = 1
    dist, grp = esdf.compute(groups, MARGINS)
    d2, _, n = esdf.update(groups, MARGINS, groups.copy(), (dist, grp))
    assert n == 0 and np.array_equal(d2, dist) and d2 is not dist
    edited = groups.copy()
    edited[62:64, 62:64, 10] = 2
    d3, g3, n = esdf.update(edited, MARGINS, groups, (dist, grp))
    assert 0 < n < edited.size // 4
    full_d, full_g = esdf.compute(edited, MARGINS)
    np.testing.assert_allclose(d3, full_d, atol=1e-5, rtol=0)
    np.testing.assert_array_equal(g3, full_g)
    assert not np.array_equal(d3, dist)


def test_mapper_incremental_equals_full_over_a_sweep_of_frames(room: list, sweep) -> None:
    """Through the mapper (solid interiors, the fill, labels changing): the incremental 3-D grid after
    every frame is the full recompute's."""
    cfg = MapperConfig(output="3d", half_extent=(1.5, 1.5, 1.0), max_distance=0.5)
    mappers = [Mapper(cfg, RiskConfig()) for _ in range(2)]
    mappers[1].output.integrator = FullEsdf.of(cfg)
    for m in mappers:
        m.set_robot_position(np.zeros(3))
    scene = [*room, Plane((0, 1, 0), -1.2, room[0].label)]
    for outs in sweep(mappers, scene, np.linspace(-0.8, 0.8, 4), 0.3):
        np.testing.assert_allclose(outs[0].distance, outs[1].distance, atol=1e-5, rtol=0)
        np.testing.assert_array_equal(outs[0].risk_group, outs[1].risk_group)
    assert (outs[0].distance < 0).any()


def test_box_edges_inside_grid_only() -> None:
    """An edit at a grid corner: the boxes clip to the grid."""
    esdf = EsdfIntegrator.of(MapperConfig(max_distance=0.15))
    groups = np.zeros((30, 30, 30), np.uint8)
    dist, grp = esdf.compute(groups, MARGINS)
    edited = groups.copy()
    edited[-3:, -3:, -3:] = 1
    d, g, _ = esdf.update(edited, MARGINS, groups, (dist, grp))
    full_d, full_g = esdf.compute(edited, MARGINS)
    np.testing.assert_allclose(d, full_d, atol=1e-5, rtol=0)
    np.testing.assert_array_equal(g, full_g)
