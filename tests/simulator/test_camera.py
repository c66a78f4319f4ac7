"""Camera model and renderer: ray geometry, pointmap ↔ world consistency, mounting, labels, RGB."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol.platforms import LIMO, CameraMount
from riskfield.services.geometry.camera import PinholeCamera, T_base_camera
from riskfield.services.geometry.transforms import pose_matrix
from riskfield.services.simulator import procedural, shapes
from riskfield.services.simulator.camera import PALETTE, Renderer
from riskfield.services.simulator.scene import NO_LABEL, Scene, SceneObject

CAM = PinholeCamera.from_fov(64, 48, 90.0)


def test_from_fov_intrinsics():
    c = PinholeCamera.from_fov(512, 384, 90.0)
    assert c.fx == pytest.approx(256.0) and c.cx == 255.5 and c.cy == 191.5
    with pytest.raises(ValueError):
        PinholeCamera(0, 10, 1, 1, 0, 0)


@settings(max_examples=50, deadline=None)
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(0.1, 20))
def test_project_inverts_rays(x, y, z):
    p = np.array([x, y, z])
    uv, front = CAM.project(p)
    assert front
    ray = np.array([(uv[0] - CAM.cx) / CAM.fx, (uv[1] - CAM.cy) / CAM.fy, 1.0])
    np.testing.assert_allclose(ray * z, p, atol=1e-9)


def test_rays_have_unit_z_and_centre_pixel_looks_forward():
    c = PinholeCamera(5, 3, 10.0, 10.0, 2.0, 1.0)
    r = c.rays()
    assert r.shape == (3, 5, 3) and np.all(r[..., 2] == 1.0)
    np.testing.assert_allclose(r[1, 2], [0, 0, 1])
    np.testing.assert_allclose(r[0, 4], [0.2, -0.1, 1], atol=1e-7)


def test_mount_looks_along_the_robot_heading():
    T = T_base_camera(CameraMount(position=(0.15, 0.0, 0.1)))
    np.testing.assert_allclose(T[:3, 2], [1, 0, 0], atol=1e-12)  # optical axis = body x
    np.testing.assert_allclose(T[:3, 0], [0, -1, 0], atol=1e-12)  # image right = body −y
    np.testing.assert_allclose(T[:3, 1], [0, 0, -1], atol=1e-12)  # image down = body −z
    Tp = T_base_camera(CameraMount(rpy_deg=(0.0, 20.0, 0.0)))
    assert Tp[2, 2] == pytest.approx(-math.sin(math.radians(20)))  # tilted towards the floor
    assert np.linalg.det(Tp[:3, :3]) == pytest.approx(1.0)


def _wall_scene(distance: float) -> Scene:
    return Scene([SceneObject("wall", 0, shapes.slab((distance, -50, -50), (distance + 0.1, 50, 50)))])


def test_render_of_a_wall_has_constant_depth_and_world_consistent_pointmap():
    r = Renderer(CAM)
    robot = np.eye(4)
    robot[:3, 3] = (1.0, 2.0, 0.0)
    T_WC = robot @ T_base_camera(CameraMount(position=(0.15, 0.0, 0.1)))
    f = r.render(_wall_scene(4.0).at(0.0), T_WC)
    np.testing.assert_allclose(f.depth, 4.0 - 1.15, atol=1e-5)
    world = f.points.reshape(-1, 3) @ T_WC[:3, :3].T + T_WC[:3, 3]
    np.testing.assert_allclose(world[:, 0], 4.0, atol=1e-5)  # every point lies on the wall's face
    assert np.all(f.labels == 0) and f.valid.all()
    uv, _ = CAM.project(f.points)  # pointmap pixel (v, u) projects back to (u, v)
    vv, uu = np.mgrid[0:CAM.height, 0:CAM.width]
    np.testing.assert_allclose(uv[..., 0], uu, atol=1e-3)
    np.testing.assert_allclose(uv[..., 1], vv, atol=1e-3)


def test_render_labels_misses_and_shading():
    scene = Scene([*procedural.room(6, 6), SceneObject("ball", 119, shapes.sphere(0.3), pose_matrix(1.0, 0))])
    T_WC = np.eye(4)
    T_WC[:3, :3] = T_base_camera(LIMO.camera)[:3, :3]
    T_WC[:3, 3] = (0, 0, 0.3)
    f = Renderer(CAM).render(scene.at(0.0), T_WC)
    assert f.labels[CAM.height // 2, CAM.width // 2] == 119
    assert f.depth[CAM.height // 2, CAM.width // 2] == pytest.approx(1.0 - 0.3, abs=0.01)
    assert f.labels[-1, CAM.width // 2] == 3 and f.labels[0, CAM.width // 2] == 5
    assert set(np.unique(f.labels)) <= {0, 3, 5, 119}
    ball = f.labels == 119
    colours = f.rgb[ball].astype(float)
    assert colours.std(axis=0).sum() > 5  # shading varies with the normal over the sphere
    base = PALETTE[119] * 255
    assert np.all(colours <= base + 1)  # shading only darkens the class colour
    empty = Renderer(CAM).render(Scene([SceneObject("b", 41, shapes.box(1, 1, 1), pose_matrix(0, 0, 10))])
                                 .at(0.0), T_WC)
    assert not empty.valid.any() and np.all(empty.labels == NO_LABEL) and np.all(empty.rgb == 0)
    assert np.all(empty.points == 0)


def test_rgb_dtype_and_shape():
    f = Renderer(CAM).render(_wall_scene(2.0).at(0.0), np.eye(4) @ np.diag([1, 1, 1, 1.0]))
    assert f.rgb.dtype == np.uint8 and f.rgb.shape == (48, 64, 3)
    assert f.points.dtype == np.float32 and f.labels.dtype == np.uint16
