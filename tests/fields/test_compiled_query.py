"""``fields.compiled.query_point`` against ``EsdfField.query`` (the oracle) on random points."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import EsdfGrid, decode, encode
from riskfield.services.fields import AnalyticField, EsdfField, to_esdf, to_grid_message
from riskfield.services.fields import compiled as fc
from riskfield.services.geometry.shapes import Plane, Sphere
from riskfield.services.runtime import jit, kernels

pytestmark = pytest.mark.skipif(not jit.HAVE_NUMBA, reason="numba is not installed")

INTERPOLATIONS = ["trilinear", "catmull_rom", "bspline", "bspline_smooth"]


def compiled_query(field: EsdfField, pts: np.ndarray, hessian: bool) -> tuple[np.ndarray, ...]:
    n = pts.shape[0]
    dist, grad, hess = np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3, 3))
    rg, inside = np.zeros(n, np.int64), np.zeros(n, np.bool_)
    view, out, scratch = fc.kernel_view(field), (dist, grad, hess, rg, inside), np.zeros(fc.QUERY_SCRATCH_SIZE)
    for i in range(n):
        fc.query_point(view, 3 if hessian else 2, pts[i], i, out, scratch)
    return dist, grad, hess, rg, inside


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), planar=st.booleans(), kind=st.sampled_from(INTERPOLATIONS),
       hessian=st.booleans())
def test_compiled_point_query_equals_the_grid_query(seed, planar, kind, hessian):
    rng = np.random.default_rng(seed)
    shapes = [Sphere(tuple(rng.uniform(-0.5, 0.5, 3)), float(rng.uniform(0.1, 0.4)), label=int(rng.integers(0, 3)),
                     planar=planar), Plane.through((0.0, -0.6, 0.0), (0.1, 1.0, 0.0), label=1)]
    field = AnalyticField(shapes, groups=["a", "b"])
    z = (0.0, 0.0) if planar else (-0.3, 0.3 + rng.uniform(0, 0.2))
    grid = to_esdf(field, [-0.8, -0.7, z[0]], [0.8 + rng.uniform(0, 0.3), 0.7, z[1]],
                   float(rng.choice([0.05, 0.1])), planar=planar).with_interpolation(kind)
    # Inside, on the border layers (extrapolated stencil) and past the map (flagged, clamped).
    pts = rng.uniform([-1.0, -0.9, -0.5], [1.2, 0.9, 0.6], (200, 3))
    pts[:10] = grid.origin + rng.uniform(0, 0.5 * grid.voxel_size, (10, 3))
    dist, grad, hess, rg, inside = compiled_query(grid, pts, hessian)
    ref = grid.query(pts, hessian=hessian)
    np.testing.assert_allclose(dist, ref.distance, atol=1e-9, rtol=0)
    np.testing.assert_allclose(grad, ref.gradient, atol=1e-8, rtol=0)
    if hessian:
        np.testing.assert_allclose(hess, ref.hessian, atol=1e-6, rtol=1e-12)
    np.testing.assert_array_equal(rg, ref.risk_group)
    np.testing.assert_array_equal(inside, ref.inside)
    assert inside.any() and not inside.all()


def test_a_decoded_message_gives_the_same_kernel_arrays():
    local = to_esdf(AnalyticField(Sphere((0.0, 0.0, 0.0), 0.3, label=1), groups=["a"]), [-1, -1, -1], [1, 1, 1], 0.1)
    wire = EsdfField.from_grid(decode(encode(to_grid_message(local)), EsdfGrid))
    a, b = fc.kernel_view(local), fc.kernel_view(wire)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert b[0].dtype == np.float64 and b[0].flags.writeable and b[1].dtype == np.uint8 and b[1].flags.writeable


if jit.HAVE_NUMBA:
    @jit.numba.njit  # no on-disk cache: a test leaves nothing behind
    def _stamp_slots(fbuf, ftab, ibuf, itab, k1, k2, k3):
        """Through the compiled views: slot k1 (1-D) += 1, k2 (2-D) [i, j] += 10 i + j, k3 (3-D)
        [i, j, l] -= 100 i + 10 j + l on the float buffer, and the int slot 0 (1-D) += its index.
        Returns the sum read back through the same views."""
        a, b, c, d = kernels.view1(fbuf, ftab, k1), kernels.view2(fbuf, ftab, k2), kernels.view3(fbuf, ftab, k3), \
            kernels.view1(ibuf, itab, 0)
        for i in range(a.shape[0]):
            a[i] += 1.0
        for i in range(b.shape[0]):
            for j in range(b.shape[1]):
                b[i, j] += 10 * i + j
        for i in range(c.shape[0]):
            for j in range(c.shape[1]):
                for m in range(c.shape[2]):
                    c[i, j, m] -= 100 * i + 10 * j + m
        for i in range(d.shape[0]):
            d[i] += i
        return a.sum() + b.sum() + c.sum()


@settings(max_examples=40, deadline=None)
@given(dims=st.lists(st.integers(1, 5), min_size=6, max_size=6), order=st.permutations([0, 1, 2]),
       n_int=st.integers(1, 7))
def test_compiled_views_are_the_layouts_slots(dims, order, n_int):
    """``view1``-``view3`` (``fields.compiled.carve`` in machine code) address exactly the slot
    ``Layout.view`` gives, in any order of slots and sizes, and write through to the buffer."""
    shapes = {"one": ("a",), "two": ("b", "c"), "three": ("d", "e", "f")}
    layout = kernels.Layout("Probe", [("pad", (3,)), *[(name, shapes[name]) for name in
                                                   (["one", "two", "three"][i] for i in order)], ("tail", (2,))])
    ints = kernels.Layout("ProbeInts", [("counts", ("g",)), ("after", (1,))])
    ftab = layout.table(**dict(zip("abcdef", dims, strict=True)))
    itab = ints.table(g=n_int)
    rng = np.random.default_rng(sum(dims))
    fbuf, ibuf = rng.normal(size=kernels.Layout.size(ftab)), np.zeros(kernels.Layout.size(itab), np.int64)
    want = fbuf.copy()
    one, two, three = (layout.view(want, ftab, name) for name in ("one", "two", "three"))
    one += 1.0
    two += 10 * np.arange(two.shape[0])[:, None] + np.arange(two.shape[1])[None, :]
    three -= (100 * np.arange(three.shape[0])[:, None, None] + 10 * np.arange(three.shape[1])[None, :, None]
              + np.arange(three.shape[2])[None, None, :])
    got = _stamp_slots(fbuf, ftab, ibuf, itab, *(int(layout.slot[s]) for s in ("one", "two", "three")))
    np.testing.assert_array_equal(fbuf, want)  # no write strays outside its slot
    assert got == pytest.approx(one.sum() + two.sum() + three.sum())
    np.testing.assert_array_equal(ints.view(ibuf, itab, "counts"), np.arange(n_int))
    assert ints.view(ibuf, itab, "after")[0] == 0
