"""Signed, semantically inflated ESDF: analytic shapes, exact margins, the dilation variant, the 2-D slice."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from riskfield.services.geometry.shapes import Box, Plane, Sphere
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.esdf_integrator import EsdfIntegrator
from riskfield.services.mapping.volume import Volume

V = 0.05


def centres(shape: tuple[int, int, int]) -> np.ndarray:
    return Volume(V, shape).centres()


def no_margins(n: int = 3) -> np.ndarray:
    return np.zeros(n + 1)


SHAPES = [
    Sphere((1.013, 0.977, 1.021), 0.43, 0),
    Sphere((0.96, 1.04, 1.0), 0.61, 0),
    # faces on voxel boundaries (half-voxel positions): the union of cubes is the box itself
    Box((0.525, 0.625, 0.425), (1.275, 1.175, 1.325), 0),
]


@pytest.mark.parametrize("shape", SHAPES, ids=["sphere", "sphere2", "box"])
def test_solid_shapes_match_exact_signed_distance_within_half_a_voxel(shape: Sphere | Box) -> None:
    c = centres((41, 41, 41))
    sdf = shape.distance(c)
    groups = np.where(sdf <= 0, 3, 0).astype(np.uint8)
    esdf = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=5.0))
    d, g = esdf.compute(groups, no_margins())
    assert np.abs(d - sdf).max() <= 0.5 * V + 1e-5
    assert np.all(g[sdf <= 0] == 3) and np.all(d[sdf <= 0] < 0) and np.all(d[sdf > 0] > 0)


def test_off_lattice_box_corners_stay_within_the_documented_bound() -> None:
    """Off the lattice a convex corner can be misplaced by up to (√3 − ½) voxel; faces stay within ½."""
    c = centres((41, 41, 41))
    box = Box((0.52, 0.61, 0.43), (1.27, 1.18, 1.33), 0)
    sdf = box.distance(c)
    d, _ = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=5.0)).compute(
        np.where(sdf <= 0, 3, 0).astype(np.uint8), no_margins())
    assert np.abs(d - sdf).max() <= (np.sqrt(3) - 0.5) * V
    # in front of a face (the nearest box point is on the face) the error is within half a voxel
    lo, hi = np.array(box.lo), np.array(box.hi)
    face = (c[..., 0] < lo[0]) & np.all((c[..., 1:] > lo[1:]) & (c[..., 1:] < hi[1:]), axis=-1)
    assert face.sum() > 100
    assert np.abs(d[face] - sdf[face]).max() <= 0.5 * V + 1e-5


def test_half_space_matches_the_plane_distance() -> None:
    c = centres((31, 21, 21))
    plane = Plane((-1, 0, 0), -0.737, 0)  # solid behind the normal: x ≥ 0.737
    signed = c[..., 0] - 0.737  # solid beyond x = 0.737
    groups = np.where(signed >= 0, 3, 0).astype(np.uint8)
    d, _ = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=5.0)).compute(groups, no_margins())
    true = plane.distance(c)
    assert np.abs(d - true).max() <= 0.5 * V + 1e-5


@pytest.mark.parametrize("shape", SHAPES[:2], ids=["sphere", "sphere2"])
def test_surface_shell_never_overestimates_the_distance(shape: Sphere) -> None:
    """The TSDF's surface support is a shell; the field is then conservative (≤ true) and within a voxel."""
    c = centres((41, 41, 41))
    sdf = shape.distance(c)
    groups = np.where(np.abs(sdf) <= 0.5 * V, 3, 0).astype(np.uint8)
    d, _ = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=5.0)).compute(groups, no_margins())
    out = (groups == 0) & (sdf > 0)
    assert np.all(d[out] <= sdf[out] + 1e-5)
    assert np.all(d[out] >= sdf[out] - V - 1e-5)


def brute_force(groups: np.ndarray, margins: np.ndarray, dmax: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The definition, voxel by voxel: each group's signed cube-convention distance − its margin;
    returns the clipped minimum, its group, and the per-group terms (inf for absent groups)."""
    c = centres(groups.shape).reshape(-1, 3)
    gflat = groups.ravel()
    occ = gflat > 0
    free_c = c[~occ]
    terms = np.full((len(margins) - 1, len(c)), np.inf)
    for g in range(1, len(margins)):
        sites = c[gflat == g]
        if len(sites) == 0:
            continue
        e = np.sqrt(((c[:, None, :] - sites[None]) ** 2).sum(-1)).min(1)
        s = e - 0.5 * V - margins[g]
        mine = gflat == g
        if len(free_c):
            e_f = np.sqrt(((c[mine][:, None, :] - free_c[None]) ** 2).sum(-1)).min(1)
            s[mine] = -(e_f - 0.5 * V) - margins[g]
        terms[g - 1] = s
    best = terms.min(axis=0)
    best_g = (terms.argmin(axis=0) + 1).astype(np.uint8)
    best_g[best >= dmax] = 0
    best = np.clip(best, -dmax, dmax)
    return best.reshape(groups.shape), best_g.reshape(groups.shape), terms.reshape(-1, *groups.shape)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.tuples(*[st.floats(0.0, 0.3)] * 3), st.floats(0.1, 0.6))
def test_margins_are_exact_in_metres(seed: int, margins: tuple[float, float, float], dmax: float) -> None:
    rng = np.random.default_rng(seed)
    shape = (9, 8, 7)
    groups = np.where(rng.random(shape) < 0.04, rng.integers(1, 4, shape), 0).astype(np.uint8)
    m = np.array([0.0, *margins])
    d, g = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=dmax)).compute(groups, m)
    ref_d, ref_g, terms = brute_force(groups, m, dmax)
    assert np.allclose(d, ref_d, atol=2e-6)
    # the group is the argmin wherever the minimum is unambiguous
    srt = np.sort(terms, axis=0)
    clear = (srt[1] - srt[0]) > 1e-5 if len(srt) > 1 else np.ones(shape, bool)
    clear &= np.abs(srt[0] - dmax) > 1e-5  # right at the clip the group may round either way
    assert np.array_equal(g[clear], ref_g[clear])
    # and where it is ambiguous, it is one of the groups attaining the minimum
    for idx in np.argwhere(~clear & (ref_g > 0)):
        i = tuple(idx)
        assert terms[g[i] - 1][i] <= srt[0][i] + 1e-5


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.15, 0.6))
def test_group_crops_are_exact_on_a_larger_grid(seed: int, dmax: float) -> None:
    """Sparse groups far apart: the per-group boxes are much smaller than the grid, yet nothing changes."""
    rng = np.random.default_rng(seed)
    shape = (34, 30, 26)
    groups = np.zeros(shape, np.uint8)
    for g, n in ((1, 3), (2, 4), (3, 12)):
        idx = rng.integers(0, shape, size=(n, 3))
        groups[tuple(idx.T)] = g
    m = np.array([0.0, 0.15, 0.05, 0.0])
    d, g = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=dmax)).compute(groups, m)
    ref_d, ref_g, terms = brute_force(groups, m, dmax)
    assert np.allclose(d, ref_d, atol=2e-6)
    srt = np.sort(terms, axis=0)
    clear = ((srt[1] - srt[0]) > 1e-5) & (np.abs(srt[0] - dmax) > 1e-5)
    assert np.array_equal(g[clear], ref_g[clear])


def test_margin_of_a_single_voxel_is_exact_and_the_dilation_variant_rounds_it() -> None:
    groups = np.zeros((41, 41, 41), np.uint8)
    groups[20, 20, 20] = 1
    m = np.array([0.0, 0.07, 0.05, 0.0])
    exact, g = EsdfIntegrator.of(MapperConfig(voxel_size=V)).compute(groups, m)
    dil, gd = EsdfIntegrator.of(MapperConfig(voxel_size=V, inflation="dilate")).compute(groups, m)
    for n in range(2, 10):
        assert exact[20 + n, 20, 20] == pytest.approx(n * V - 0.5 * V - 0.07, abs=1e-6)
        # dilation by round(0.07 / 0.05) = 1 voxel: the margin becomes 0.05 m
        assert dil[20 + n, 20, 20] == pytest.approx((n - 1) * V - 0.5 * V, abs=1e-6)
    assert exact[20, 20, 20] == pytest.approx(-0.5 * V - 0.07, abs=1e-6)
    assert g[25, 20, 20] == 1 and gd[25, 20, 20] == 1
    # the zero level set sits exactly 0.07 m (plus the half voxel) from the centre along x
    x = np.arange(41) * V
    row = exact[:, 20, 20].astype(float)
    k = 21  # between voxels 21 and 22 the sign changes
    assert row[k] < 0 < row[k + 1]
    zero = x[k] + V * row[k] / (row[k] - row[k + 1])
    assert zero - x[20] == pytest.approx(0.5 * V + 0.07, abs=1e-6)


def test_nearest_group_and_clipping() -> None:
    groups = np.zeros((61, 5, 5), np.uint8)
    groups[10, 2, 2] = 3  # low, no margin
    groups[40, 2, 2] = 1  # high, 0.15 m
    m = np.array([0.0, 0.15, 0.05, 0.0])
    d, g = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=1.0)).compute(groups, m)
    # midway-ish: at x index 26 the low voxel is 16 voxels (0.8 m) away, the high one 14 (0.7 − 0.15)
    assert g[26, 2, 2] == 1 and d[26, 2, 2] == pytest.approx(0.7 - 0.025 - 0.15, abs=1e-6)
    assert g[12, 2, 2] == 3
    # far from both: clipped to max_distance, no group
    groups2 = np.zeros((61, 5, 5), np.uint8)
    groups2[0, 2, 2] = 2
    d2, g2 = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=0.5)).compute(groups2, m)
    assert d2.max() == pytest.approx(0.5) and np.all(g2[d2 >= 0.5] == 0) and g2[3, 2, 2] == 2
    assert d2.min() >= -0.5


def test_empty_occupancy_is_max_distance_everywhere() -> None:
    d, g = EsdfIntegrator.of(MapperConfig(max_distance=1.25)).compute(np.zeros((7, 8, 9), np.uint8), no_margins())
    assert np.all(d == np.float32(1.25)) and not g.any()


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_slice_is_the_min_over_the_band_of_the_3d_field(seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape = (24, 20, 12)
    groups = np.where(rng.random(shape) < 0.01, rng.integers(1, 4, shape), 0).astype(np.uint8)
    k_lo, k_hi = 3, 8
    m = np.array([0.0, 0.15, 0.05, 0.0])
    esdf = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=0.8))
    d2, _ = esdf.compute_slice(groups, k_lo, k_hi, m)
    assert d2.shape == (24, 20, 1)
    band_only = np.zeros_like(groups)
    band_only[:, :, k_lo:k_hi] = groups[:, :, k_lo:k_hi]
    d3, _ = esdf.compute(band_only, m)
    ref = d3[:, :, k_lo:k_hi].min(axis=2)
    free_cols = ~(groups[:, :, k_lo:k_hi] > 0).any(axis=2)
    assert np.allclose(d2[:, :, 0][free_cols], ref[free_cols], atol=2e-6)
    assert np.all(d2[:, :, 0][~free_cols] < 0)
    # obstacles outside the band (floor, ceiling) are ignored
    outside = np.zeros_like(groups)
    outside[:, :, :k_lo] = 3
    d_out, g_out = esdf.compute_slice(outside, k_lo, k_hi, m)
    assert np.all(d_out == np.float32(0.8)) and not g_out.any()


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_one_multi_label_edt_gives_both_sides_of_a_solid(seed: int) -> None:
    """Solid obstacles are deep almost everywhere: the multi-label EDT path must equal the two
    binary EDTs (outside distance and inside depth) it replaces."""
    rng = np.random.default_rng(seed)
    union = np.zeros((30, 24, 20), dtype=bool)
    for _ in range(4):
        lo = rng.integers(0, [26, 20, 16])
        hi = lo + rng.integers(2, 9, size=3)
        union[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = True
    esdf = EsdfIntegrator.of(MapperConfig(voxel_size=V, max_distance=5.0))
    depth, outside = esdf._inside(union)
    v = (V,) * 3
    inside_true = edt_binary(union, v)
    outside_true = edt_binary(~union, v)
    deep = union & (inside_true > V + 1e-6)
    if deep.any():
        assert outside is not None  # the grown box of the deep voxels covers most of this grid
        assert np.allclose(outside, outside_true, atol=1e-6)
    assert np.allclose(depth[union], inside_true[union], atol=1e-6)
    assert np.all(depth[~union] == 0)


def edt_binary(mask: np.ndarray, anisotropy: tuple[float, ...]) -> np.ndarray:
    """scipy's EDT (distance of each True voxel to the nearest False one), an independent oracle."""
    return ndimage.distance_transform_edt(mask, sampling=anisotropy).astype(np.float32)
