"""The compiled distance transform under the ESDF (``distance_transform``) against the ``edt`` package.
The ESDF built on it against the ESDF built on ``edt`` (``esdf_edt``): ``test_esdf_kernels``."""

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
