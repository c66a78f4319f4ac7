"""The compiled distance transform under the ESDF (``distance_transform``) against the ``edt`` package,
and the ESDF built on it against the ESDF built on ``edt`` (``esdf_edt``)."""

from __future__ import annotations

import edt as edt_package
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.distance_transform import edt
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


block = st.tuples(st.integers(-3, 30), st.integers(-3, 26), st.integers(-3, 22),
                  st.integers(1, 14), st.integers(1, 14), st.integers(1, 14), st.integers(1, 3))


@settings(max_examples=30, deadline=None)
@given(blocks=st.lists(block, min_size=1, max_size=6), noise=st.floats(0.0, 0.02),
       margins=st.tuples(st.sampled_from([0.0, 0.05, 0.15]), st.sampled_from([0.0, 0.05]), st.just(0.0)),
       dmax=st.sampled_from([0.3, 1.0, 2.0]), seed=st.integers(0, 2**16))
def test_esdf_on_it_equals_the_esdf_on_the_edt_package(blocks: list, noise: float, margins: tuple, dmax: float,
                                                      seed: int) -> None:
    """Solid blocks (deep interiors whose depth comes from the learnt box pad) and speckle: the field
    is the one the ``edt`` package gives, in distance everywhere; the risk group wherever the two
    best terms are not a float32 tie."""
    shape = (30, 26, 22)
    groups = np.zeros(shape, np.uint8)
    for i, j, k, a, b, c, g in blocks:
        groups[max(i, 0):max(i + a, 0), max(j, 0):max(j + b, 0), max(k, 0):max(k + c, 0)] = g
    rng = np.random.default_rng(seed)
    speckle = rng.random(shape) < noise
    groups[speckle] = rng.integers(1, 4, size=int(speckle.sum()))
    m = np.array([0.0, *margins])
    ours = EsdfIntegrator(MapperConfig(max_distance=dmax))
    theirs = EsdfIntegrator(MapperConfig(max_distance=dmax, esdf_edt="edt"))
    d, g = ours.compute(groups, m)
    d_ref, g_ref = theirs.compute(groups, m)
    np.testing.assert_allclose(d, d_ref, atol=1e-5, rtol=0)
    # Where the risk groups differ, the two groups' terms tie (equal margins, equidistant groups)
    # and float32 rounding picked differently: each group's term there, from the reference EDT.
    v = 0.05
    occupied = groups != 0
    depth = reference(~occupied, v)
    term = {0: np.full(shape, np.float32(dmax))}
    for h in range(1, 4):
        t = reference(groups == h, v) - np.float32(v / 2) - np.float32(m[h]) if (groups == h).any() \
            else np.full(shape, np.inf, np.float32)
        own = groups == h
        t[own] = -(depth[own] - np.float32(v / 2)) - np.float32(m[h])
        term[h] = np.minimum(t, dmax)
    differ = np.flatnonzero(g != g_ref)
    ours_t = np.array([term[int(a)].flat[x] for a, x in zip(g.flat[differ], differ, strict=True)])
    ref_t = np.array([term[int(a)].flat[x] for a, x in zip(g_ref.flat[differ], differ, strict=True)])
    np.testing.assert_allclose(ours_t, ref_t, atol=1e-5, rtol=0)


def test_deep_voxels_deeper_than_the_learnt_pad_grow_the_box() -> None:
    """The depth box pad is learnt from the last call: a shallow solid, then a much deeper one; the
    second call must find the pad too small, grow the box, and still give the exact depth."""
    cfg = MapperConfig(max_distance=2.0)
    esdf = EsdfIntegrator(cfg)
    reference_esdf = EsdfIntegrator(MapperConfig(max_distance=2.0, esdf_edt="edt"))
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
