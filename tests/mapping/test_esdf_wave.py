"""The wavefront ESDF (``esdf_incremental = "wave"``) against the full recompute (the oracle)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from riskfield.protocol import RiskConfig
from riskfield.services.geometry.shapes import Plane
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.esdf_integrator import EsdfIntegrator
from riskfield.services.mapping.esdf_wave import WaveEsdf
from riskfield.services.mapping.mapper import Mapper
from riskfield.services.mapping.volume import shift_array

SHAPE = (36, 32, 28)

edit = st.tuples(
    st.integers(0, SHAPE[0] - 1), st.integers(0, SHAPE[1] - 1), st.integers(0, SHAPE[2] - 1),
    st.integers(1, 9), st.integers(1, 9), st.integers(1, 9), st.integers(0, 4),
)


def apply(groups: np.ndarray, e: tuple[int, ...]) -> None:
    i, j, k, a, b, c, g = e
    groups[i:i + a, j:j + b, k:k + c] = g  # 0 removes; another id relabels what was there


def group_terms(groups: np.ndarray, margins: np.ndarray, v: float) -> np.ndarray:
    """T_g of every group at every voxel (inf where g is absent), by scipy's EDT in float64: the
    independent reference for which labels tie."""
    depth = ndimage.distance_transform_edt(groups != 0) * v
    out = np.full((margins.shape[0], *groups.shape), np.inf)
    for g in range(1, margins.shape[0]):
        mask = groups == g
        if mask.any():
            e = ndimage.distance_transform_edt(~mask) * v
            out[g] = np.where(mask, -(depth - 0.5 * v), e - 0.5 * v) - margins[g]
    return out


def assert_same_field(d: np.ndarray, g: np.ndarray, full_d: np.ndarray, full_g: np.ndarray, groups: np.ndarray,
                      margins: np.ndarray, cfg: MapperConfig) -> None:
    """Distances within 1e-5 m; the risk group the oracle's, except where two groups' terms tie
    (equal within 1e-5 m in exact arithmetic): there float32 rounding decides in each, and the wave's
    group must be one whose term is the minimum. (The oracle's union term carries the base group's
    label even where another group of the same margin is the nearer one, so a rounding of it can
    name the base there; the wave names the group of the site it found.)"""
    np.testing.assert_allclose(d, full_d, atol=1e-5, rtol=0)
    differ = np.argwhere(g != full_g)
    if differ.size == 0:
        return
    terms = group_terms(groups, margins, cfg.voxel_size)
    terms[0] = cfg.max_distance  # label 0: nothing in range (the clip)
    for idx in map(tuple, differ):
        t = terms[(slice(None), *idx)]
        best = min(float(t[1:].min()), cfg.max_distance)
        assert abs(t[full_g[idx]] - best) <= 1e-5 or margins[full_g[idx]] == min(margins[1:][t[1:] < np.inf]), idx
        assert t[g[idx]] <= best + 1e-5, (idx, g[idx], full_g[idx], t, best)


@settings(max_examples=30, deadline=None)
@given(start=st.lists(edit, min_size=0, max_size=6),
       edits=st.lists(st.lists(edit, min_size=1, max_size=3), min_size=1, max_size=5),
       max_distance=st.sampled_from([0.2, 0.35, 0.6]),
       margins=st.sampled_from([(0.0, 0.15, 0.05, 0.0, 0.3), (0.0, 0.0, 0.1, 0.0, 0.02), (0.0, 0.2, 0.2, 0.1, 0.0)]))
def test_wave_equals_full_recompute_on_random_edit_sequences(start: list, edits: list, max_distance: float,
                                                             margins: tuple) -> None:
    """Adds, removals, relabels, several in a row, four risk groups with different margins."""
    cfg = MapperConfig(max_distance=max_distance, threads=1)
    oracle = EsdfIntegrator.of(cfg)
    wave = WaveEsdf(cfg.voxel_size, cfg.max_distance)
    m = np.array(margins)
    groups = np.zeros(SHAPE, np.uint8)
    for e in start:
        apply(groups, e)
    d, g, n = wave.update(groups, m)
    assert_same_field(d, g, *oracle.compute(groups, m), groups, m, cfg)
    for step in edits:
        before = groups.copy()
        for e in step:
            apply(groups, e)
        d, g, n = wave.update(groups, m)
        assert_same_field(d, g, *oracle.compute(groups, m), groups, m, cfg)
        assert n > 0 or np.array_equal(before, groups)


def test_a_local_edit_touches_only_what_it_changes() -> None:
    """One voxel added beside a wall moves only the voxels nearer to it than to the wall; removing it
    again restores the field exactly. Through ``EsdfIntegrator.update`` (the option)."""
    cfg = MapperConfig(max_distance=0.5, esdf_incremental="wave")
    esdf = EsdfIntegrator.of(cfg)
    margins = np.array([0.0, 0.15, 0.05, 0.0])
    groups = np.zeros((60, 60, 40), np.uint8)
    groups[:, :, 0:2] = 3
    d0, g0, n0 = esdf.update(groups, margins, groups, (None, None))  # type: ignore[arg-type]
    assert n0 > 0  # the first call builds the maps
    bump = groups.copy()
    bump[30, 30, 2] = 3
    d1, g1, n1 = esdf.update(bump, margins, groups, (d0, g0))
    assert 0 < n1 < 2000
    assert_same_field(d1, g1, *esdf.compute(bump, margins), bump, margins, cfg)
    d2, g2, _ = esdf.update(groups, margins, bump, (d1, g1))
    np.testing.assert_array_equal(d2, d0)
    np.testing.assert_array_equal(g2, g0)
    person = groups.copy()
    person[30, 30, 2:6] = 1  # a higher-margin group on the wall: its inflation wins nearby
    d3, g3, _ = esdf.update(person, margins, groups, (d2, g2))
    assert_same_field(d3, g3, *esdf.compute(person, margins), person, margins, cfg)
    assert g3[30, 30, 1] == 1 and d3[30, 30, 1] < d0[30, 30, 1]


def test_new_shape_or_margins_start_over() -> None:
    cfg = MapperConfig(max_distance=0.3)
    wave, oracle = WaveEsdf(cfg.voxel_size, cfg.max_distance), EsdfIntegrator.of(cfg)
    groups = np.zeros((20, 20, 20), np.uint8)
    groups[5:9, 5:9, 5:9] = 2
    for margins in (np.array([0.0, 0.1, 0.0]), np.array([0.0, 0.1, 0.2])):
        d, g, _ = wave.update(groups, margins)
        assert_same_field(d, g, *oracle.compute(groups, margins), groups, margins, cfg)
    shifted = np.roll(groups, (3, -2, 1), axis=(0, 1, 2))  # most of the map moves: rebuilt from empty
    shifted[0, 0, 0:4] = 1
    d, g, n = wave.update(shifted, margins)
    assert n == shifted.size  # every value redone
    assert_same_field(d, g, *oracle.compute(shifted, margins), shifted, margins, cfg)
    small = groups[:12, :12, :12].copy()
    d, g, _ = wave.update(small, margins)
    assert d.shape == small.shape
    assert_same_field(d, g, *oracle.compute(small, margins), small, margins, cfg)


@settings(max_examples=15, deadline=None)
@given(start=st.lists(edit, min_size=1, max_size=6), after=st.lists(edit, min_size=0, max_size=2),
       delta=st.tuples(st.integers(-6, 6), st.integers(-6, 6), st.integers(-6, 6)))
def test_wave_follows_a_volume_shift(start: list, after: list, delta: tuple) -> None:
    """The maps move with the volume (``volume.shift_array``), sites left behind are lost, entering
    voxels are free; then an edit: the field is the full recompute's."""
    cfg = MapperConfig(max_distance=0.35, threads=1)
    oracle, wave = EsdfIntegrator.of(cfg), WaveEsdf(cfg.voxel_size, cfg.max_distance)
    m = np.array([0.0, 0.15, 0.05, 0.0, 0.3])
    groups = np.zeros(SHAPE, np.uint8)
    for e in start:
        apply(groups, e)
    wave.update(groups, m)
    shift_array(groups, np.array(delta), 0)
    wave.shift(np.array(delta))
    for e in after:
        apply(groups, e)
    d, g, n = wave.update(groups, m)
    assert n == groups.size or not any(delta)
    assert_same_field(d, g, *oracle.compute(groups, m), groups, m, cfg)


def test_mapper_sweep_wave_against_full_recompute(room: list, sweep) -> None:
    """Through the mapper (solid interiors, the fill, labels changing) over a camera sweep: the wave's
    field is the full recompute's. Nearest-site propagation over 26 neighbours can miss the nearest
    site of a voxel whose nearest site is no neighbour's (digital Voronoi islands, far from the
    obstacles); such misses are counted and must stay rare and below a tenth of a voxel."""
    mappers = [Mapper(MapperConfig(output="3d", half_extent=(1.5, 1.5, 1.0), max_distance=0.8,
                                   esdf_incremental=u), RiskConfig()) for u in ("wave", "box")]
    scene = [*room, Plane((0, 1, 0), -1.2, room[0].label)]  # no robot position: the volume follows the camera
    misses = 0
    for outs in sweep(mappers, scene, np.linspace(-0.8, 0.8, 5), 0.6):
        err = np.abs(outs[0].distance - outs[1].distance)
        misses += int((err > 1e-5).sum())
        assert err.max() <= 0.1 * mappers[0].config.voxel_size
        ok = err <= 1e-5
        d, g = outs[0].distance.copy(), outs[0].risk_group.copy()
        d[~ok], g[~ok] = outs[1].distance[~ok], outs[1].risk_group[~ok]  # the misses: checked above
        assert_same_field(d, g, outs[1].distance, outs[1].risk_group, mappers[0].occupancy(), mappers[0].margins,
                          mappers[0].config)
    assert misses <= 10
    assert (outs[0].distance < 0).any() and mappers[0].shifts > 0
