"""The grid query (``protocol.field.query_point``, through ``EsdfField.query``) against the array oracle
(``oracles.field.array_query``) on random points, compiled and interpreted."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.field import array_query
from riskfield.protocol import EsdfGrid, decode, encode, kernels
from riskfield.protocol import field as pf
from riskfield.services.fields import AnalyticField, EsdfField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Plane, Sphere

INTERPOLATIONS = ["trilinear", "catmull_rom", "bspline", "bspline_smooth"]


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), planar=st.booleans(), kind=st.sampled_from(INTERPOLATIONS),
       hessian=st.booleans())
def test_the_grid_query_equals_the_array_oracle(seed, planar, kind, hessian):
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
    got, ref = grid.query(pts, hessian=hessian), array_query(grid, pts, hessian=hessian)
    np.testing.assert_allclose(got.distance, ref.distance, atol=1e-9, rtol=0)
    np.testing.assert_allclose(got.gradient, ref.gradient, atol=1e-8, rtol=0)
    if hessian:
        np.testing.assert_allclose(got.hessian, ref.hessian, atol=1e-6, rtol=1e-12)
    else:
        assert got.hessian is None
    np.testing.assert_array_equal(got.risk_group, ref.risk_group)
    np.testing.assert_array_equal(got.inside, ref.inside)
    np.testing.assert_array_equal(got.inside, grid.inside(pts))
    assert got.inside.any() and not got.inside.all()


def test_the_interpreted_query_is_the_compiled_one():
    """Without numba the same ``query_point`` runs as Python (a client without the extra): the
    ``py_func`` of each kernel, driven by the same loop, gives the compiled answer."""
    if not kernels.HAVE_NUMBA:
        pytest.skip("numba is not installed: the query here is the interpreted one already")
    rng = np.random.default_rng(7)
    grid = to_esdf(AnalyticField(Sphere((0.1, 0.0, 0.0), 0.3, label=1), groups=["a"]), [-0.8, -0.8, -0.4],
                   [0.8, 0.8, 0.4], 0.1).with_interpolation("bspline_smooth")
    pts = rng.uniform(-0.9, 0.9, (40, 3))
    view, n = pf.kernel_view(grid), len(pts)
    out = (np.empty(n), np.empty((n, 3)), np.empty((n, 3, 3)), np.empty(n, np.int64), np.empty(n, np.bool_))
    scratch = np.empty(pf.QUERY_SCRATCH_SIZE)
    for i in range(n):
        pf.query_point.py_func(view, 3, pts[i], i, out, scratch)
    got = grid.query(pts, hessian=True)
    np.testing.assert_allclose(out[0], got.distance, atol=1e-12)
    np.testing.assert_allclose(out[1], got.gradient, atol=1e-12)
    np.testing.assert_allclose(out[2], got.hessian, atol=1e-10)
    np.testing.assert_array_equal(out[3], got.risk_group)
    np.testing.assert_array_equal(out[4], got.inside)


def test_a_decoded_message_gives_the_same_kernel_arrays():
    local = to_esdf(AnalyticField(Sphere((0.0, 0.0, 0.0), 0.3, label=1), groups=["a"]), [-1, -1, -1], [1, 1, 1], 0.1)
    wire = EsdfField.from_grid(decode(encode(to_grid_message(local)), EsdfGrid))
    a, b = pf.kernel_view(local), pf.kernel_view(wire)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert b[0].dtype == np.float64 and b[0].flags.writeable and b[1].dtype == np.uint8 and b[1].flags.writeable


if kernels.HAVE_NUMBA:
    @kernels.numba.njit  # no on-disk cache: a test leaves nothing behind
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


@pytest.mark.skipif(not kernels.HAVE_NUMBA, reason="numba is not installed: no compiled views to test")
@settings(max_examples=40, deadline=None)
@given(dims=st.lists(st.integers(1, 5), min_size=6, max_size=6), order=st.permutations([0, 1, 2]),
       n_int=st.integers(1, 7))
def test_compiled_views_are_the_layouts_slots(dims, order, n_int):
    """``view1``-``view3`` (``protocol.kernels.carve`` in machine code) address exactly the slot
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
