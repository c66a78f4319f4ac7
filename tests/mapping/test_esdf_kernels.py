"""The compiled 3-D ESDF passes against the array path and the ``edt`` package (``oracles.esdf``), on
random group maps."""

from __future__ import annotations

import edt as edt_package
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.esdf import EdtEsdf, NumpyEsdf
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.esdf_integrator import EsdfIntegrator

block = st.tuples(
    st.integers(-3, 33), st.integers(-3, 29), st.integers(-3, 25),  # may start beyond the border: clipped
    st.integers(1, 12), st.integers(1, 12), st.integers(1, 12), st.integers(0, 4),  # group 4 > n: ignored
)


def group_map(shape: tuple[int, int, int], blocks: list, noise: float, seed: int) -> np.ndarray:
    """Solid blocks (deep interiors, at the border, touching each other) and scattered single voxels
    (exposed-only shells) of random groups."""
    groups = np.zeros(shape, np.uint8)
    for i, j, k, a, b, c, g in blocks:
        groups[max(i, 0):max(i + a, 0), max(j, 0):max(j + b, 0), max(k, 0):max(k + c, 0)] = g
    rng = np.random.default_rng(seed)
    speckle = rng.random(shape) < noise
    groups[speckle] = rng.integers(1, 4, size=int(speckle.sum()))
    return groups


@settings(max_examples=40, deadline=None)
@given(blocks=st.lists(block, min_size=0, max_size=8), noise=st.floats(0.0, 0.03),
       margins=st.tuples(st.sampled_from([0.0, 0.05, 0.12, 0.15]), st.sampled_from([0.0, 0.05, 0.15]),
                         st.sampled_from([0.0, 0.05])),
       dmax=st.sampled_from([0.2, 0.5, 1.0, 2.0]), seed=st.integers(0, 2**16))
def test_compiled_equals_numpy_path(blocks: list, noise: float, margins: tuple, dmax: float, seed: int) -> None:
    """The same distances and risk groups, bit for bit up to 1e-5 m."""
    groups = group_map((32, 28, 24), blocks, noise, seed)
    m = np.array([0.0, *margins])
    fast = EsdfIntegrator.of(MapperConfig(max_distance=dmax, threads=1))
    slow = NumpyEsdf.of(MapperConfig(max_distance=dmax, threads=1))
    d, g = fast.compute(groups, m)
    d_ref, g_ref = slow.compute(groups, m)
    assert d.dtype == np.float32 and g.dtype == np.uint8
    np.testing.assert_allclose(d, d_ref, atol=1e-5, rtol=0)
    np.testing.assert_array_equal(g, g_ref)
    assert np.isfinite(d).all() and np.abs(d).max() <= np.float32(dmax)  # the field is float32


@settings(max_examples=30, deadline=None)
@given(blocks=st.lists(block, min_size=1, max_size=6), noise=st.floats(0.0, 0.02),
       margins=st.tuples(st.sampled_from([0.0, 0.05, 0.15]), st.sampled_from([0.0, 0.05]), st.just(0.0)),
       dmax=st.sampled_from([0.3, 1.0, 2.0]), seed=st.integers(0, 2**16))
def test_compiled_edt_equals_the_edt_package_under_the_field(blocks: list, noise: float, margins: tuple,
                                                             dmax: float, seed: int) -> None:
    """The field on the compiled EDT is the one on the ``edt`` package: in distance everywhere; in
    risk group wherever the two best terms are not a float32 tie."""
    shape = (30, 26, 22)
    groups = group_map(shape, blocks, noise, seed)
    groups[groups > 3] = 0  # unknown ids are free in the field: the terms below see them so
    m = np.array([0.0, *margins])
    d, g = EsdfIntegrator.of(MapperConfig(max_distance=dmax)).compute(groups, m)
    d_ref, g_ref = EdtEsdf.of(MapperConfig(max_distance=dmax)).compute(groups, m)
    np.testing.assert_allclose(d, d_ref, atol=1e-5, rtol=0)
    # Where the risk groups differ, the two groups' terms tie (equal margins, equidistant groups)
    # and float32 rounding picked differently: each group's term there, from the ``edt`` package.
    v = 0.05
    ref = lambda sites: edt_package.edt((~sites).astype(np.uint8), anisotropy=(v,) * 3,  # noqa: E731
                                        black_border=False)
    depth = ref(groups == 0)
    term = {0: np.full(shape, np.float32(dmax))}
    for h in range(1, 4):
        own = groups == h
        t = ref(own) - np.float32(v / 2) - np.float32(m[h]) if own.any() else np.full(shape, np.inf, np.float32)
        t[own] = -(depth[own] - np.float32(v / 2)) - np.float32(m[h])
        term[h] = np.minimum(t, dmax)
    differ = np.flatnonzero(g != g_ref)
    ours_t = np.array([term[int(a)].flat[x] for a, x in zip(g.flat[differ], differ, strict=True)])
    ref_t = np.array([term[int(a)].flat[x] for a, x in zip(g_ref.flat[differ], differ, strict=True)])
    np.testing.assert_allclose(ours_t, ref_t, atol=1e-5, rtol=0)


def test_compiled_path_sees_deep_interiors_in_a_sub_box() -> None:
    """A small solid far from the rest: its depth comes from the EDT of a box around it, not the grid."""
    groups = np.zeros((90, 90, 40), np.uint8)
    groups[40:52, 40:52, 5:17] = 1  # deep interior, box ≪ half the grid at max_distance 0.3
    groups[0, :, :] = 3
    m = np.array([0.0, 0.15, 0.05, 0.0])
    cfg = {"max_distance": 0.3}
    d, g = EsdfIntegrator.of(MapperConfig(**cfg)).compute(groups, m)
    d_ref, g_ref = NumpyEsdf.of(MapperConfig(**cfg)).compute(groups, m)
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
