"""Never-observed space below an observed obstacle (``unobserved_below_obstacle``, issue 13).

Regression of the safety benchmark's bed: its top was seen only at a grazing angle (viewing
direction nearly horizontal, so the fill along it reached 0.15 m down) and its long side by no
frame, so below a thin lid the bed read as free space, +0.075 m at 0.2 m height. The layers are
set by hand: one column through a lid, never-observed space and the observed floor.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.occupancy import close_pinholes_by_voxel, whole_volume_occupancy
from riskfield.protocol import RiskConfig, ade20k
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.layers import SemanticLayer, TsdfLayer
from riskfield.services.mapping.occupancy import _FREE, OccupancyRule, _close_pinholes, semantic_occupancy

V = 0.05
BED, FLOOR = ade20k.index("bed"), ade20k.index("floor")
SHAPE = (5, 5, 24)


def layers(free_at: int | None = None) -> tuple[TsdfLayer, SemanticLayer]:
    """Columns: the floor surface observed at k = 2 (free label), never observed from k = 3 to 15,
    the bed's observed interior at k = 16 and its labelled top at k = 17 (seen along a grazing,
    nearly horizontal ray), observed free space above. ``free_at``: one observed free voxel in
    the gap (seen under the lid)."""
    tsdf, sem = TsdfLayer(SHAPE, 0.15), SemanticLayer(SHAPE)
    tsdf.weight[:, :, 18:] = 10.0
    tsdf.tsdf[:, :, 18:] = 0.15
    tsdf.weight[:, :, 16:18] = 10.0
    tsdf.tsdf[:, :, 17] = 0.0
    tsdf.tsdf[:, :, 16] = -0.1
    tsdf.view[:, :, 16] = (120, 0, -20)
    sem.label[:, :, 17] = BED
    tsdf.weight[:, :, :3] = 10.0
    tsdf.tsdf[:, :, 2] = 0.0
    tsdf.tsdf[:, :, :2] = -0.1
    sem.label[:, :, 2] = FLOOR
    if free_at is not None:
        tsdf.weight[:, :, free_at] = 10.0
        tsdf.tsdf[:, :, free_at] = 0.15
    return tsdf, sem


def occupancy(support_steps: int, free_at: int | None = None) -> np.ndarray:
    tsdf, sem = layers(free_at)
    lut = RiskConfig().label_to_group()
    return semantic_occupancy(tsdf, sem, lut, OccupancyRule(0.5, 0.75 * V, interior="solid", fill_steps=10,
                                                            support_steps=support_steps))


def test_never_observed_space_below_an_obstacle_joins_it() -> None:
    bed_group = int(RiskConfig().label_to_group()[BED])
    assert bed_group > 0
    hollow = occupancy(0)[2, 2]
    assert np.all(hollow[3:16] == 0)  # the lid over free space the benchmark's robot flew into
    solid = occupancy(20)[2, 2]
    assert np.all(solid[3:18] == bed_group)
    assert np.all(solid[:3] == 0) and np.all(solid[18:] == 0)  # the floor and the space above stay free


def test_the_fill_below_stops_at_its_depth_and_at_observed_space() -> None:
    short = occupancy(4)[2, 2]
    assert np.all(short[12:16] > 0) and np.all(short[3:12] == 0)
    seen = occupancy(20, free_at=9)[2, 2]  # a ray crossed under the lid at k = 9
    assert np.all(seen[10:16] > 0) and seen[9] == 0 and np.all(seen[3:9] == 0)


@pytest.mark.parametrize(("policy", "steps"), [("solid", 20), ("free", 0)])
def test_the_policy_and_depth_come_from_the_config(policy: str, steps: int) -> None:
    c = MapperConfig(unobserved_below_obstacle=policy)
    assert c.support_steps == steps
    assert MapperConfig(unobserved_behind_surface="free").support_steps == 0  # needs the solid fill


@pytest.mark.parametrize(("seed", "height"), [*((s, (4, 18)) for s in range(6)), (6, (65, 70)), (7, (120, 140))])
def test_the_sparse_scans_equal_the_whole_volume_scans(seed: int, height: tuple[int, int]) -> None:
    """The production passes skip columns without an observed obstacle and voxels the wavefront
    never reached, and close pinholes on bit planes of 64 voxels a word; on random layers (blobs of
    labelled surface, interior, never-observed space, grazing and steep viewing directions) they
    give the whole-volume scans' result (the oracle), also in columns of two and three words."""
    rng = np.random.default_rng(seed)
    shape = (*(int(n) for n in rng.integers(4, 18 if height[1] < 64 else 9, 2)), int(rng.integers(*height)))
    tsdf, sem = TsdfLayer(shape, 0.15), SemanticLayer(shape)
    observed = rng.random(shape) < 0.6
    tsdf.weight[observed] = rng.uniform(0.0, 10.0, int(observed.sum()))
    tsdf.tsdf[...] = rng.choice([-0.1, 0.0, 0.01, 0.15], size=shape).astype(np.float32)
    tsdf.view[...] = rng.integers(-127, 128, (*shape, 3)).astype(np.int8)
    labelled = rng.random(shape) < 0.3
    sem.label[labelled] = rng.choice([BED, FLOOR, ade20k.index("wall"), ade20k.index("person")],
                                     int(labelled.sum()))
    lut = RiskConfig().label_to_group()
    for unknown_group in (0, 2):
        for fill, support in ((0, 0), (3, 0), (3, 4), (10, 20)):
            rule = OccupancyRule(0.5, 0.75 * V, unknown_group, "solid", fill, support)
            full = whole_volume_occupancy(tsdf, sem, lut, rule)
            np.testing.assert_array_equal(semantic_occupancy(tsdf, sem, lut, rule), full)
    assert full.any()


@settings(max_examples=150, deadline=None)
@given(nx=st.integers(1, 4), ny=st.integers(1, 4), nz=st.integers(1, 140), seed=st.integers(0, 2**32 - 1),
       p_filled=st.floats(0.0, 0.6))
def test_the_pinholes_close_on_bit_planes_as_voxel_by_voxel(nx: int, ny: int, nz: int, seed: int,
                                                            p_filled: float) -> None:
    """The bit planes (``_close_pinholes``, 64 voxels of a column to a word, bits carried across
    words along k) close the same voxels with the same groups as the six-neighbour scan, for any
    column height: words end at k = 63, 127."""
    rng = np.random.default_rng(seed)
    shape = np.array([nx, ny, nz], np.int64)
    n = nx * ny * nz
    state = rng.choice(np.array([0, 1, 2, 3], np.uint8), n, p=[0.1, 0.05, 0.6, 0.25])
    g = np.where(state == 3, rng.choice(np.array([0, 1, 2, 3, _FREE], np.uint8), n), 0).astype(np.uint8)
    filled = (state == 2) & (rng.random(n) < p_filled)
    g[filled] = rng.integers(1, 4, int(filled.sum()))
    marked = np.flatnonzero(filled)
    results = []
    for close in (_close_pinholes, close_pinholes_by_voxel):
        st_, g_, filled_ = state.copy(), g.copy(), filled.copy()
        cand = np.zeros(n, np.int64)
        cand[:marked.size] = marked
        n_filled = close(st_, filled_, g_, cand, marked.size, shape)
        np.testing.assert_array_equal(st_, state)  # both leave the caller's state as it was
        results.append((g_, filled_, np.sort(cand[marked.size:n_filled])))
    (g_bits, filled_bits, closed_bits), (g_ref, filled_ref, closed_ref) = results
    np.testing.assert_array_equal(closed_bits, closed_ref)
    np.testing.assert_array_equal(filled_bits, filled_ref)
    np.testing.assert_array_equal(g_bits, g_ref)
