"""The compiled 3-D ESDF passes (``esdf_kernel = "numba"``) against the numpy path, on random group maps."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.esdf_integrator import EsdfIntegrator

block = st.tuples(
    st.integers(-3, 33), st.integers(-3, 29), st.integers(-3, 25),  # may start beyond the border: clipped
    st.integers(1, 12), st.integers(1, 12), st.integers(1, 12), st.integers(0, 4),  # group 4 > n: ignored
)


@settings(max_examples=40, deadline=None)
@given(blocks=st.lists(block, min_size=0, max_size=8), noise=st.floats(0.0, 0.03),
       margins=st.tuples(st.sampled_from([0.0, 0.05, 0.12, 0.15]), st.sampled_from([0.0, 0.05, 0.15]),
                         st.sampled_from([0.0, 0.05])),
       dmax=st.sampled_from([0.2, 0.5, 1.0, 2.0]), seed=st.integers(0, 2**16))
def test_compiled_equals_numpy_path(blocks: list, noise: float, margins: tuple, dmax: float, seed: int) -> None:
    """Solid blocks (deep interiors, at the border, touching each other) and scattered single voxels
    (exposed-only shells): the same distances and risk groups, bit for bit up to 1e-5 m."""
    shape = (32, 28, 24)
    groups = np.zeros(shape, np.uint8)
    for i, j, k, a, b, c, g in blocks:
        groups[max(i, 0):max(i + a, 0), max(j, 0):max(j + b, 0), max(k, 0):max(k + c, 0)] = g
    rng = np.random.default_rng(seed)
    speckle = rng.random(shape) < noise
    groups[speckle] = rng.integers(1, 4, size=int(speckle.sum()))
    m = np.array([0.0, *margins])
    fast = EsdfIntegrator(MapperConfig(max_distance=dmax, esdf_kernel="numba", threads=1))
    slow = EsdfIntegrator(MapperConfig(max_distance=dmax, esdf_kernel="numpy", threads=1))
    d, g = fast.compute(groups, m)
    d_ref, g_ref = slow.compute(groups, m)
    assert d.dtype == np.float32 and g.dtype == np.uint8
    np.testing.assert_allclose(d, d_ref, atol=1e-5, rtol=0)
    np.testing.assert_array_equal(g, g_ref)
    assert np.isfinite(d).all() and np.abs(d).max() <= dmax


def test_compiled_path_sees_deep_interiors_in_a_sub_box() -> None:
    """A small solid far from the rest: its depth comes from the EDT of a box around it, not the grid."""
    groups = np.zeros((90, 90, 40), np.uint8)
    groups[40:52, 40:52, 5:17] = 1  # deep interior, box ≪ half the grid at max_distance 0.3
    groups[0, :, :] = 3
    m = np.array([0.0, 0.15, 0.05, 0.0])
    cfg = {"max_distance": 0.3}
    d, g = EsdfIntegrator(MapperConfig(**cfg)).compute(groups, m)
    d_ref, g_ref = EsdfIntegrator(MapperConfig(esdf_kernel="numpy", **cfg)).compute(groups, m)
    np.testing.assert_allclose(d, d_ref, atol=1e-5, rtol=0)
    np.testing.assert_array_equal(g, g_ref)
    assert d[46, 46, 11] < -0.2  # six voxels deep: −(0.3 − 0.025) − 0.15, clipped to −0.3


@settings(max_examples=40, deadline=None)
@given(shape=st.tuples(st.integers(1, 12), st.integers(1, 12), st.integers(1, 12)), flips=st.integers(0, 5),
       seed=st.integers(0, 2**16))
def test_diff_box_is_the_bounding_box_of_the_changed_voxels(shape: tuple, flips: int, seed: int) -> None:
    """The incremental update's changed box (one parallel pass) against the mask-and-reduce one."""
    from riskfield.services.mapping import esdf_kernels as k

    rng = np.random.default_rng(seed)
    a = rng.integers(0, 3, size=shape).astype(np.uint8)
    b = a.copy()
    idx = rng.integers(0, a.size, size=flips)
    b.flat[idx] = (b.flat[idx] + 1) % 3
    lo, hi = k.diff_box(a, b)
    changed = np.argwhere(a != b)
    if changed.size == 0:
        assert (hi <= lo).all()
    else:
        np.testing.assert_array_equal(lo, changed.min(axis=0))
        np.testing.assert_array_equal(hi, changed.max(axis=0) + 1)
