"""Scenes: primitives are watertight, ground-truth signed distance matches analytic distances,
ray casting through the snapshot's tables returns the right labels, motion and appearance work,
procedural rooms are deterministic and non-overlapping."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.sim_camera import cast
from riskfield.protocol import ade20k
from riskfield.services.geometry.transforms import pose_matrix
from riskfield.services.simulator import procedural, shapes
from riskfield.services.simulator.mesh_io import is_closed
from riskfield.services.simulator.scene import NO_LABEL, Motion, Scene, SceneObject


def box_sdf(p: np.ndarray, centre: np.ndarray, half: np.ndarray) -> np.ndarray:
    q = np.abs(p - centre) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return outside + inside


@pytest.mark.parametrize("mesh", [shapes.box(1, 2, 3), shapes.sphere(0.3), shapes.ellipsoid(0.4, 0.2, 0.3),
                                  shapes.cylinder(0.2, 1.0), shapes.capsule(0.2, 1.7), shapes.person(),
                                  shapes.animal(), shapes.slab((0, 0, 0), (1, 1, 0.1))])
def test_primitives_are_closed_surfaces(mesh):
    v, t = mesh
    assert is_closed(t)
    assert np.isfinite(v).all() and t.max() < len(v)


def test_capsule_has_its_height_and_radius():
    v, _ = shapes.capsule(0.2, 1.7)
    assert v[:, 2].min() == pytest.approx(0.0, abs=1e-6) and v[:, 2].max() == pytest.approx(1.7, abs=1e-6)
    assert np.hypot(v[:, 0], v[:, 1]).max() == pytest.approx(0.2, abs=1e-6)
    with pytest.raises(ValueError):
        shapes.capsule(0.5, 0.5)


@settings(max_examples=40, deadline=None)
@given(st.floats(-2, 2), st.floats(-2, 2), st.floats(-2, 2))
def test_box_signed_distance_matches_analytic(x, y, z):
    centre = np.array([0.3, -0.2, 0.5])
    half = np.array([0.5, 0.25, 0.4])
    scene = Scene([SceneObject("b", 41, shapes.box(*(2 * half)), pose_matrix(0.3, -0.2, 0.1))])
    p = np.array([[x, y, z]])
    got = scene.signed_distance(p)[0]
    assert got == pytest.approx(box_sdf(p, centre, half)[0], abs=1e-4)


def test_sphere_signed_distance_within_tessellation_error():
    r = 0.5
    scene = Scene([SceneObject("ball", 119, shapes.sphere(r, resolution=32), pose_matrix(0, 0, 0))])
    rng = np.random.default_rng(0)
    p = rng.uniform(-1.5, 1.5, (500, 3)) + np.array([0, 0, r])
    expect = np.linalg.norm(p - [0, 0, r], axis=1) - r
    got = scene.signed_distance(p)
    sag = r * (1 - math.cos(math.pi / 32))  # chord sagitta of the tessellation
    assert np.abs(got - expect).max() < sag + 1e-3
    assert np.all(np.sign(got[np.abs(expect) > 0.02]) == np.sign(expect[np.abs(expect) > 0.02]))


def test_room_interior_is_free_and_walls_are_inside():
    scene = Scene(procedural.room(4.0, 3.0, 2.5))
    d = scene.signed_distance(np.array([[0, 0, 1.0], [1.9, 0, 1.0], [0, 1.45, 2.0], [-2.05, 0, 1.0], [0, 0, -0.05]]))
    np.testing.assert_allclose(d[:3], [1.0, 0.1, 0.05], atol=1e-4)
    assert d[3] < 0 and d[4] < 0  # inside a wall slab and inside the floor slab


def test_cast_returns_hit_distance_normal_label_and_object():
    scene = Scene([*procedural.room(6, 6), SceneObject("dog", 126, shapes.box(0.5, 0.5, 1.0),
                                                        pose_matrix(2.0, 0, 0.001))])
    o = np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0.5], [0, 0, 0.5]])
    d = np.array([[1, 0, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], float)
    h = cast(scene.at(), o, d)
    np.testing.assert_allclose(h.t, [1.75, 3.0, 0.5, 2.0], atol=1e-5)
    assert h.label.tolist() == [126, 0, 3, 5]
    assert scene.objects[h.object[0]].name == "dog"
    np.testing.assert_allclose(np.abs(h.normal[0]), [1, 0, 0], atol=1e-6)
    box = Scene([SceneObject("b", 41, shapes.box(1, 1, 1))])
    miss = cast(box.at(), np.array([0, 0, -0.5]), np.array([0, 0, -1.0]))
    assert not miss.hit and miss.label == NO_LABEL and miss.object == -1


def test_per_triangle_labels_are_looked_up():
    v, t = shapes.box(1, 1, 1)
    labels = np.full(len(t), 15, np.uint16)
    up = np.einsum("ij,ij->i", np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), [[0, 0, 1]] * len(t)) > 0
    labels[up] = 7
    scene = Scene([SceneObject("m", 15, (v, t), triangle_labels=labels)])
    h = cast(scene.at(), np.array([[0, 0, 3.0], [3, 0, 0.5]]), np.array([[0, 0, -1.0], [-1, 0, 0]]))
    assert h.label.tolist() == [7, 15]


def test_motion_paths():
    m = Motion(np.array([[0, 0], [2, 0]]), speed=1.0, mode="pingpong")
    p, yaw = m.place(np.zeros(2), 0.0, 0.5)
    np.testing.assert_allclose(p, [0.5, 0])
    assert yaw == pytest.approx(0.0)
    p, yaw = m.place(np.zeros(2), 0.0, 3.0)  # on the way back
    np.testing.assert_allclose(p, [1.0, 0])
    assert abs(abs(yaw) - math.pi) < 1e-9
    loop = Motion(np.array([[0, 0], [1, 0], [1, 1]]), 1.0, "loop")  # closes back to the start: 2 + √2 long
    p, _ = loop.place(np.zeros(2), 0, 2.0 + math.sqrt(2) + 1.5)
    np.testing.assert_allclose(p, [1, 0.5], atol=1e-9)
    p, _ = Motion(np.array([[0, 0], [1, 0]]), 1.0, "once").place(np.zeros(2), 0, 10)
    np.testing.assert_allclose(p, [1, 0])
    p, yaw = Motion(velocity=(0.0, 0.5)).place(np.array([1.0, 1.0]), 0.0, 2.0)
    np.testing.assert_allclose(p, [1, 2])
    assert yaw == pytest.approx(math.pi / 2)


def test_moving_and_appearing_objects_change_the_snapshot():
    walker = SceneObject("walker", 12, shapes.person(), pose_matrix(0, 0, 0.001),
                         motion=Motion(np.array([[0, 0], [4, 0]]), 1.0))
    late = SceneObject("late", 41, shapes.box(0.4, 0.4, 0.4), pose_matrix(0, 3, 0.001), appear_at_s=5.0)
    scene = Scene([walker, late])
    probe = np.array([[2.0, 0, 1.0], [0, 3, 0.2]])
    d0 = scene.signed_distance(probe, t=0.0)
    d2 = scene.signed_distance(probe, t=2.0)
    d6 = scene.signed_distance(probe, t=6.0)
    assert d0[0] > 1.5 and d2[0] < 0  # the walker reached x = 2
    assert d0[1] > 1.0 and d6[1] < 0  # the late box is there after 5 s
    n = scene.rebuilds
    scene.at(6.0)
    assert scene.rebuilds == n  # nothing changed: cached


def test_scene_rejects_bad_objects():
    with pytest.raises(ValueError):
        SceneObject("x", 500, shapes.box(1, 1, 1))
    v, t = shapes.box(1, 1, 1)
    with pytest.raises(ValueError):
        SceneObject("x", 1, (v, t + 100))
    bad = v.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError):
        SceneObject("x", 1, (bad, t))
    s = Scene([SceneObject("a", 1, (v, t))])
    with pytest.raises(ValueError):
        s.add(SceneObject("a", 1, (v, t)))


FULL = procedural.Furnishing(furniture=5, boxes=3, balls=2, people=2, animals=2)


def test_procedural_room_is_deterministic_and_objects_do_not_overlap():
    a = procedural.random_placements(42, 6.0, 5.0, FULL)
    b = procedural.random_placements(42, 6.0, 5.0, FULL)
    c = procedural.random_placements(43, 6.0, 5.0, FULL)
    assert a == b and a != c
    assert len(a) >= 10
    objs = procedural.build_objects(a)
    scene = Scene([*procedural.room(6.0, 5.0), *objs])
    for o in objs:
        v = o.world_mesh()[0]
        assert v[:, 0].min() >= -3.0 - 1e-6 and v[:, 0].max() <= 3.0 + 1e-6  # inside the room
        assert v[:, 1].min() >= -2.5 - 1e-6 and v[:, 1].max() <= 2.5 + 1e-6
        assert v[:, 2].min() > 0  # lifted off the floor
        assert math.hypot(o.pose[0, 3], o.pose[1, 3]) > 0.8  # the robot's start stays clear
    for i, oi in enumerate(objs):  # no vertex of one object inside another
        others = Scene([oj for j, oj in enumerate(objs) if j != i])
        assert scene is not None and np.all(others.signed_distance(oi.world_mesh()[0]) > 0)
    names = {ade20k.CLASSES[o.label] for o in objs}
    assert {"box", "ball", "person", "animal"} <= names
