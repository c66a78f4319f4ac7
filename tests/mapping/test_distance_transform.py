"""The compiled distance transform under the ESDF (``distance_transform``) against the ``edt`` package.
The ESDF built on it against the ESDF built on ``edt`` (``oracles.esdf.EdtEsdf``): ``test_esdf_kernels``."""

from __future__ import annotations

import edt as edt_package
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.esdf import EdtEsdf
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.distance_transform import edt, edt_of_label, inside_depth
from riskfield.services.mapping.esdf_integrator import EsdfIntegrator


def reference(sites: np.ndarray, voxel: float) -> np.ndarray:
    return edt_package.edt((~sites).astype(np.uint8), anisotropy=(voxel,) * sites.ndim, black_border=False)


@settings(max_examples=80, deadline=None)
@given(shape=st.lists(st.integers(1, 23), min_size=2, max_size=3),
       density=st.sampled_from([0.001, 0.02, 0.3, 0.9, 1.0]), voxel=st.sampled_from([0.05, 0.1, 1.0]),
       threads=st.integers(1, 2), seed=st.integers(0, 2**16))
def test_equals_the_edt_package(shape: list[int], density: float, voxel: float, threads: int, seed: int) -> None:
    """Random site sets in 2-D and 3-D grids (thin, flat and cubic): the same distances, 0 on the
    sites, to float32 rounding."""
    sites = np.random.default_rng(seed).random(shape) < density
    out = edt(sites, voxel, threads)
    assert out.shape == sites.shape and out.dtype == np.float32
    if not sites.any():
        assert np.isposinf(out).all()
        return
    assert (out[sites] == 0).all()
    np.testing.assert_allclose(out, reference(sites, voxel), rtol=1e-6, atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(shape=st.lists(st.integers(1, 21), min_size=2, max_size=3), density=st.sampled_from([0.01, 0.2, 1.0]),
       grow=st.lists(st.integers(0, 4), min_size=6, max_size=6), threads=st.integers(1, 2),
       seed=st.integers(0, 2**16))
def test_a_site_box_changes_nothing_but_the_cost(shape: list[int], density: float, grow: list[int], threads: int,
                                                 seed: int) -> None:
    """Sites in a random sub-box of a grid (a risk group in its reach box): told that box (exactly
    or loosely, even past the grid), the transform is bit-equal to the one that searches the whole
    grid, on a strided view too."""
    rng = np.random.default_rng(seed)
    n = len(shape)
    lo = np.array([rng.integers(0, s) for s in shape])
    hi = np.array([rng.integers(a, s) for a, s in zip(lo, shape, strict=True)])
    sites = np.zeros(shape, bool)
    inner = tuple(slice(a, b + 1) for a, b in zip(lo, hi, strict=True))
    sites[inner] = rng.random(sites[inner].shape) < density
    labels = np.where(sites, 3, 1).astype(np.uint8)
    whole = edt_of_label(labels, 3, True, 0.05, threads)
    loose = (lo - np.array(grow[:n]), hi + np.array(grow[3:3 + n]))
    told = edt_of_label(labels, 3, True, 0.05, threads, site_box=loose)
    np.testing.assert_array_equal(told, whole)
    big = np.zeros(tuple(2 * s for s in shape), np.uint8)
    view = big[tuple(slice(0, None, 2) for _ in shape)]
    view[...] = labels
    np.testing.assert_array_equal(edt_of_label(view, 3, True, 0.05, threads, site_box=(lo, hi)), whole)


@settings(max_examples=80, deadline=None)
@given(shape=st.lists(st.integers(1, 19), min_size=3, max_size=3), density=st.sampled_from([0.05, 0.3, 0.7, 0.97, 1.0]),
       solid=st.booleans(), threads=st.integers(1, 2), seed=st.integers(0, 2**16))
def test_inside_depth_is_the_transform_to_the_free_voxels(shape: list[int], density: float, solid: bool, threads: int,
                                                          seed: int) -> None:
    """Random occupancy (speckle, or a solid block with speckle around it, up to a full grid with no
    free voxel): where the depth array is negative, the distance to the nearest free voxel, as the
    full transform gives it (+inf with none); every other voxel untouched."""
    rng = np.random.default_rng(seed)
    labels = (rng.random(shape) < density).astype(np.uint8) * rng.integers(1, 4, size=shape).astype(np.uint8)
    if solid:
        labels[tuple(slice(n // 4, n - n // 4) for n in shape)] = 2
    occupied = labels != 0
    depth = np.where(occupied, np.float32(0.05), np.float32(0.0)).astype(np.float32)
    marked = occupied & (rng.random(shape) < 0.6)
    depth[marked] = -1.0
    before = depth.copy()
    if occupied.any():
        idx = np.argwhere(occupied)
        inside_depth(labels, depth, idx.min(axis=0), idx.max(axis=0), 0.05, threads)
    exact = edt(~occupied, 0.05, threads)
    np.testing.assert_array_equal(depth[marked], exact[marked])
    np.testing.assert_array_equal(depth[~marked], before[~marked])


def test_distances_are_exact_on_known_geometry() -> None:
    """One site in a corner of an elongated grid: every distance is √(i² + j² + k²)·v, the far corner
    included; the squared distances are whole voxels, so there is no rounding beyond float32's."""
    sites = np.zeros((40, 7, 90), bool)
    sites[0, 0, 0] = True
    out = edt(sites, 0.05, threads=2)
    i, j, k = np.indices(sites.shape)
    expected = (np.sqrt((i * i + j * j + k * k).astype(np.float32)) * np.float32(0.05)).astype(np.float32)
    np.testing.assert_array_equal(out, expected)


def test_no_site_is_infinite_and_a_bad_grid_is_refused() -> None:
    assert np.isposinf(edt(np.zeros((5, 6, 7), bool), 0.05)).all()
    with pytest.raises(ValueError, match="2-D or 3-D"):
        edt(np.zeros(5, bool), 0.05)


def test_a_deep_solid_after_a_shallow_one_has_its_exact_depth() -> None:
    """A shallow solid, then a much deeper one: nothing the first call leaves behind bounds the
    second's inside depth."""
    cfg = MapperConfig(max_distance=2.0)
    esdf = EsdfIntegrator.of(cfg)
    reference_esdf = EdtEsdf.of(MapperConfig(max_distance=2.0))
    m = np.array([0.0, 0.0])
    shallow = np.zeros((60, 60, 60), np.uint8)
    shallow[10:14, 10:14, 10:14] = 1
    esdf.compute(shallow, m)
    deep = np.zeros((60, 60, 60), np.uint8)
    deep[5:55, 5:55, 5:55] = 1  # 25 voxels deep at the centre: past any pad learnt above
    d, _ = esdf.compute(deep, m)
    d_ref, _ = reference_esdf.compute(deep, m)
    np.testing.assert_allclose(d, d_ref, atol=1e-5, rtol=0)
    assert d[30, 30, 30] == pytest.approx(-(25 * 0.05 - 0.025), abs=1e-6)
