"""Rolling volume geometry: lattice snapping, world ↔ index, shifts that keep the overlap."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.layers import NO_LABEL, SemanticLayer, TsdfLayer
from riskfield.services.mapping.volume import Volume, shift_array

coord = st.floats(-50, 50, allow_nan=False)


def test_the_default_volume_is_a_ground_robots_wider_and_flatter_than_the_authors_cube() -> None:
    """3 m along the floor (a person is tracked that far), 1.25 m up and down (the slice's band and
    what hangs over it), in fewer voxels than the authors' 101³, whose shape stays one setting away."""
    c = MapperConfig()
    assert c.shape == (121, 121, 51) and c.half_extent[0] >= 3.0 and c.band[1] < c.half_extent[2]
    assert np.prod(c.shape) < 101**3
    assert MapperConfig(half_extent=(2.5, 2.5, 2.5)).shape == (101, 101, 101)


@given(st.tuples(coord, coord, coord))
def test_centred_volume_sits_on_the_lattice_and_contains_the_centre(c: tuple[float, float, float]) -> None:
    vol = Volume.centred(0.05, (21, 21, 21), np.array(c))
    # voxel centres lie on multiples of the voxel size
    assert np.allclose(vol.origin / 0.05, np.round(vol.origin / 0.05))
    # the middle voxel is the one nearest the requested centre
    assert np.abs(vol.centre - np.array(c)).max() <= 0.025 + 1e-9
    idx = vol.to_index(np.array(c))
    assert np.array_equal(idx, [10, 10, 10])


@given(st.lists(st.tuples(coord, coord, coord), min_size=1, max_size=20))
def test_world_index_round_trip(points: list) -> None:
    vol = Volume(0.05, (10, 10, 10), (3, -7, 100))
    p = np.array(points)
    idx = vol.to_index(p)
    # the voxel a point falls in has its centre within half a voxel on every axis
    assert np.abs(vol.to_world(idx) - p).max() <= 0.025 + 1e-9
    assert np.allclose(vol.to_world(vol.to_continuous(p)), p)


@settings(max_examples=60)
@given(st.tuples(*[st.integers(-7, 7)] * 3), st.integers(0, 2**31 - 1))
def test_shift_keeps_every_overlapping_voxel_and_clears_the_rest(delta: tuple[int, int, int], seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape = (6, 5, 4)
    old = rng.normal(size=shape).astype(np.float32)
    new = old.copy()
    shift_array(new, np.array(delta), fill=-99.0)
    for i, j, k in np.ndindex(shape):
        src = (i + delta[0], j + delta[1], k + delta[2])
        if all(0 <= s < n for s, n in zip(src, shape, strict=True)):
            assert new[i, j, k] == old[src]
        else:
            assert new[i, j, k] == -99.0


def test_layers_shift_together_with_the_volume() -> None:
    vol = Volume.centred(0.1, (11, 11, 11), np.zeros(3))
    tsdf, sem = TsdfLayer(vol.shape, 0.3), SemanticLayer(vol.shape)
    world = np.array([0.3, -0.2, 0.1])
    i = tuple(vol.to_index(world))
    tsdf.tsdf[i], tsdf.weight[i], sem.label[i], sem.vote[i] = 0.01, 5.0, 12, 2.5
    delta = vol.shift_to(vol.origin_index_for(np.array([0.4, 0.3, -0.2])))
    tsdf.shift(delta)
    sem.shift(delta)
    j = tuple(vol.to_index(world))
    assert j != i
    assert (tsdf.tsdf[j], tsdf.weight[j], sem.label[j], sem.vote[j]) == (np.float32(0.01), 5.0, 12, 2.5)
    # voxels that entered the volume are unknown
    assert tsdf.weight[-1, -1, 0] == 0 and sem.label[-1, -1, 0] == NO_LABEL and tsdf.tsdf[-1, -1, 0] == np.float32(0.3)


def test_a_centre_halfway_between_voxels_is_still_the_middle_voxel() -> None:
    # 0.125 / 0.05 = 2.5: a tie; the grid and the index must break it the same way
    vol = Volume.centred(0.05, (21, 21, 21), np.array([0.0, 0.0, 0.125]))
    assert np.array_equal(vol.to_index(np.array([0.0, 0.0, 0.125])), [10, 10, 10])
