"""The pinhole model: unproject ∘ project is the identity, rays are the unprojection at depth 1."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.geometry.camera import PinholeCamera

cameras = st.builds(
    PinholeCamera,
    width=st.integers(2, 640),
    height=st.integers(2, 480),
    fx=st.floats(50.0, 1000.0),
    fy=st.floats(50.0, 1000.0),
    cx=st.floats(-10.0, 650.0),
    cy=st.floats(-10.0, 490.0),
)
coords = st.floats(-1e3, 1e3)


@settings(max_examples=200, deadline=None)
@given(cam=cameras, u=coords, v=coords, z=st.floats(1e-3, 100.0))
def test_project_of_unproject_is_the_identity(cam: PinholeCamera, u: float, v: float, z: float) -> None:
    p = cam.unproject(np.array([u, v]), np.array(z))
    assert p[2] == pytest.approx(z)
    uv, front = cam.project(p)
    assert front
    np.testing.assert_allclose(uv, [u, v], rtol=1e-9, atol=1e-9 * (1 + abs(u) + abs(v)))


@settings(max_examples=200, deadline=None)
@given(cam=cameras, x=st.floats(-50, 50), y=st.floats(-50, 50), z=st.floats(1e-2, 100.0))
def test_unproject_of_project_is_the_identity(cam: PinholeCamera, x: float, y: float, z: float) -> None:
    p = np.array([x, y, z])
    uv, front = cam.project(p)
    assert front
    np.testing.assert_allclose(cam.unproject(uv, np.array(z)), p, rtol=1e-9, atol=1e-9)


def test_points_behind_the_camera_are_flagged() -> None:
    _, front = PinholeCamera().project(np.array([[0.0, 0.0, -1.0], [0.1, 0.2, 0.0], [0.0, 0.0, 2.0]]))
    assert front.tolist() == [False, False, True]


@settings(max_examples=30, deadline=None)
@given(cam=cameras.filter(lambda c: c.width * c.height <= 20_000))
def test_rays_are_the_unprojection_at_unit_depth_and_unit_rays_their_directions(cam: PinholeCamera) -> None:
    rays = cam.rays(np.float64)
    assert rays.shape == (cam.height, cam.width, 3)
    v, u = np.mgrid[0 : cam.height, 0 : cam.width]
    expect = cam.unproject(np.stack([u, v], axis=-1).astype(float), np.ones((cam.height, cam.width)))
    np.testing.assert_allclose(rays, expect, atol=1e-12)
    unit = cam.unit_rays()
    np.testing.assert_allclose(np.linalg.norm(unit, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(unit * rays[..., 2:] / unit[..., 2:], rays, atol=1e-9)
    # A ray's pixel is itself: the optical centre of pixel (u, v) projects back onto (u, v).
    uv, _ = cam.project(rays)
    np.testing.assert_allclose(uv, np.stack([u, v], axis=-1), atol=1e-9)


def test_from_fov_and_centred_put_the_principal_point_at_the_image_centre() -> None:
    c = PinholeCamera.from_fov(512, 384, 90.0)
    assert c.fx == pytest.approx(256.0) and (c.cx, c.cy) == (255.5, 191.5)
    assert PinholeCamera.centred(160, 120, 125.0) == PinholeCamera(160, 120, 125.0, 125.0, 79.5, 59.5)
    np.testing.assert_allclose(c.K @ np.array([0.0, 0.0, 1.0]), [255.5, 191.5, 1.0])


@pytest.mark.parametrize("bad", [dict(width=0), dict(fx=-1.0), dict(cy=float("nan"))])
def test_invalid_intrinsics_are_rejected(bad: dict) -> None:
    with pytest.raises(ValueError):
        PinholeCamera(**bad)
