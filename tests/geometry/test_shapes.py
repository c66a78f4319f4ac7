"""The one shape family: ray hits lie on the surface, the exact distance's derivatives match
finite differences, the analytic field is the union of its shapes, and rendering is the camera's."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from riskfield.services.fields import AnalyticField
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Plane, Sphere, render
from riskfield.services.geometry.transforms import look_at

coord = st.floats(-2.0, 2.0)
point = st.tuples(coord, coord, coord)
direction = st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 0.1)

spheres = st.builds(Sphere, center=point, radius=st.floats(0.1, 1.0), label=st.integers(0, 3), planar=st.booleans())
boxes = st.builds(lambda lo, size, label: Box(lo, tuple(np.add(lo, size)), label), point,
                  st.tuples(*[st.floats(0.1, 1.5)] * 3), st.integers(0, 3))
planes = st.builds(Plane.through, point, direction, st.integers(0, 3))
shapes = st.one_of(spheres, boxes, planes)


def unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


@settings(max_examples=300, deadline=None)
@given(shape=shapes, o=point, d=direction)
def test_ray_hits_lie_on_the_surface_and_nothing_is_hit_before(shape, o, d) -> None:
    o, d = np.asarray(o), unit(d)
    assume(shape.distance(o) > 1e-3)  # cast from outside
    t = float(shape.intersect(o[None], d[None])[0])
    if np.isfinite(t):
        assert t > 0
        assert abs(shape.distance(o + t * d)) < 1e-9
        before = o + np.linspace(0.0, 1.0 - 1e-6, 50)[:, None] * t * d
        assert np.all(shape.distance(before) > -1e-9)
    else:
        along = o + np.linspace(0.0, 20.0, 2000)[:, None] * d
        assert np.all(shape.distance(along) > -1e-9)  # a missed ray never enters the solid


@settings(max_examples=200, deadline=None)
@given(shape=st.one_of(spheres, boxes), o=point)
def test_a_ray_cast_at_the_centre_from_outside_hits(shape, o) -> None:
    o = np.asarray(o)
    c = np.asarray(shape.center)
    if isinstance(shape, Sphere) and shape.planar:
        c = np.array([c[0], c[1], o[2]])
    assume(shape.distance(o) > 1e-3)
    t = float(shape.intersect(o[None], unit(c - o)[None])[0])
    assert np.isfinite(t) and t <= np.linalg.norm(c - o) + 1e-9


def _smooth_enough(shape, x: np.ndarray, h: float = 1e-3) -> bool:
    """Away from the kinks of the distance (a sphere's centre, a box's medial axis inside and the
    boundaries between its face/edge/corner regions outside, where the Hessian jumps).

    A box's medial axis inside is where two faces are equally near: two adjacent faces (the two
    largest ``q`` tie) or the two opposite faces of the nearest pair (the mid-plane ``rel[k] = 0``,
    where the distance is ``|rel[k]| − half[k]``: a V, whose central difference is 0 whatever the
    gradient picks)."""
    if isinstance(shape, Sphere):
        return float(shape.distance(x)) + shape.radius > 10 * h
    if isinstance(shape, Box):
        q, _ = shape._q(x)
        if (q <= 0).all():
            top = np.sort(q)
            k = int(np.argmax(q))
            mid_plane = abs(float(x[k] - shape.center[k])) <= 10 * h
            return top[-1] - top[-2] > 10 * h and not mid_plane
        return bool(np.all(np.abs(q) > 10 * h))
    return True


@settings(max_examples=300, deadline=None)
@given(shape=shapes, x=point)
def test_gradient_and_hessian_match_finite_differences(shape, x) -> None:
    x = np.asarray(x, np.float64)
    assume(_smooth_enough(shape, x))
    h = 1e-6
    E = np.eye(3)
    fd_grad = np.array([(shape.distance(x + h * e) - shape.distance(x - h * e)) / (2 * h) for e in E])
    np.testing.assert_allclose(shape.gradient(x), fd_grad, atol=1e-6)
    hh = 1e-5
    fd_hess = np.array([(shape.gradient(x + hh * e) - shape.gradient(x - hh * e)) / (2 * hh) for e in E]).T
    np.testing.assert_allclose(shape.hessian(x), fd_hess, atol=1e-4 * (1 + np.abs(fd_hess).max()))
    if not (isinstance(shape, Sphere) and shape.planar):
        assert np.linalg.norm(shape.gradient(x)) == pytest.approx(1.0)


@settings(max_examples=100, deadline=None)
@given(lo=point, size=st.tuples(*[st.floats(0.1, 1.5)] * 3), axis=st.integers(0, 2), t=st.floats(0.05, 0.95),
       s=st.floats(0.05, 0.95))
def test_on_a_boxs_mid_plane_the_gradient_is_one_of_the_two_nearest_faces_normals(lo, size, axis, t, s) -> None:
    """The mid-plane between the nearest pair of opposite faces is a kink (the distance is
    ``|rel| − half`` across it): no finite difference to match, but the gradient is still a
    subgradient there, the outward normal of one of the two faces, and each side's one-sided
    derivative is that side's normal."""
    box = Box(lo, tuple(np.add(lo, size)))
    half, c = box.half, box.center
    assume(half[axis] < np.delete(half, axis).min() - 1e-3)  # this pair of faces is the nearest
    others = [a for a in range(3) if a != axis]
    x = c.copy()
    for a, f in zip(others, (t, s), strict=True):  # anywhere on the mid-plane nearer this pair than the rest
        x[a] = c[a] + (2 * f - 1) * (half[a] - half[axis])
    e = np.eye(3)[axis]
    g = box.gradient(x)
    assert any(np.allclose(g, n) for n in (e, -e))
    h = 1e-6
    assert (box.distance(x + h * e) - box.distance(x)) / h == pytest.approx(1.0, abs=1e-6)
    assert (box.distance(x - h * e) - box.distance(x)) / h == pytest.approx(1.0, abs=1e-6)


@settings(max_examples=100, deadline=None)
@given(parts=st.lists(shapes, min_size=1, max_size=5), pts=st.lists(point, min_size=1, max_size=20))
def test_the_analytic_field_is_the_nearest_of_its_shapes(parts: list, pts: list) -> None:
    field = AnalyticField(parts, groups=["high", "mid", "low"])
    p = np.asarray(pts, np.float64)
    s = field.query(p, hessian=True)
    each = np.stack([sh.distance(p) for sh in parts], axis=1)
    np.testing.assert_allclose(s.distance, each.min(axis=1), atol=1e-12)
    assert s.inside.all()
    for i in range(len(p)):
        k = int(np.argmin(each[i]))
        if len(parts) > 1 and np.diff(np.sort(each[i])[:2])[0] < 1e-9:
            continue  # a tie: either shape is the nearest
        np.testing.assert_allclose(s.gradient[i], parts[k].gradient(p[i]), atol=1e-12)
        np.testing.assert_allclose(s.hessian[i], parts[k].hessian(p[i]), atol=1e-9)
        assert s.risk_group[i] == parts[k].label


def test_render_hits_project_back_to_their_pixels_at_the_true_surface() -> None:
    cam = PinholeCamera.centred(40, 30, 30.0)
    scene = [Plane((1, 0, 0), 1.5, 7), Sphere((1.0, 0.2, 0.3), 0.25, 5), Box((0.8, -0.6, 0.0), (1.0, -0.3, 0.6), 9)]
    T = look_at(np.array([0.0, 0.0, 0.3]), np.array([1.0, 0.0, 0.3]))
    points, conf, labels = render(scene, T, cam)
    hit = conf > 0
    assert hit.all() and set(np.unique(labels).tolist()) == {5, 7, 9}
    uv, front = cam.project(points.astype(np.float64))
    v, u = np.mgrid[0:30, 0:40]
    assert front.all()
    np.testing.assert_allclose(uv, np.stack([u, v], axis=-1), atol=1e-3)  # float32 storage
    world = points.reshape(-1, 3).astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    nearest = np.min(np.stack([np.abs(s.distance(world)) for s in scene]), axis=0)
    assert nearest.max() < 1e-5
