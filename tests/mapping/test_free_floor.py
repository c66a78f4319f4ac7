"""The floor seen free (``free_floor``, ``EsdfGrid.observed_free``): only where rays crossed it,
never an obstacle, forgotten after ``observed_free_s``, kept in place when the volume moves."""

from __future__ import annotations

import numpy as np

from riskfield.protocol import ade20k
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.mapper import Mapper

#: OpenCV camera (x right, y down, z forward) looking along world +x
R_WC = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
CAM_Z, WALL_X = 0.2, 1.5


def frame(cam_x: float = 0.0, h: int = 48, w: int = 64, f: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """A pointmap (camera frame) of the floor z = 0 and a wall at x = WALL_X, and its T_WC."""
    u, v = np.meshgrid(np.arange(w) + 0.5 - w / 2, np.arange(h) + 0.5 - h / 2)
    d_cam = np.stack([u / f, v / f, np.ones_like(u)], axis=-1)
    d_w = d_cam @ R_WC.T
    t_wall = (WALL_X - cam_x) / d_w[..., 0]
    t_floor = np.where(d_w[..., 2] < 0, CAM_Z / np.maximum(-d_w[..., 2], 1e-9), np.inf)
    t = np.minimum(t_wall, t_floor)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_WC, (cam_x, 0.0, CAM_Z)
    return (d_cam * t[..., None]).astype(np.float32), T


def mapper(**cfg) -> Mapper:
    m = Mapper(MapperConfig(half_extent=(2.5, 2.5, 1.0), **cfg))
    m.set_robot_position(np.zeros(3))
    return m


def integrate(m: Mapper, stamp_s: float, cam_x: float = 0.0) -> None:
    pts, T = frame(cam_x)
    labels = np.full(pts.shape[:2], ade20k.index("wall"), np.uint16)
    m.integrate(pts, np.ones(pts.shape[:2], np.float32), labels, T, stamp_ns=int(stamp_s * 1e9))


def free_at(m: Mapper, x: float, y: float = 0.0) -> int:
    g = m.update_esdf().slice2d
    i, j = np.floor((np.array([x, y]) - np.array(g.origin[:2])) / g.voxel_size + 0.5).astype(int)
    return int(g.observed_free[i, j, 0])


def test_only_floor_the_rays_crossed_is_free_and_never_an_obstacle():
    m = mapper()
    integrate(m, 1.0)
    g = m.update_esdf().slice2d
    assert g.observed_free is not None and g.observed_free.shape == g.distance.shape
    assert free_at(m, 0.8) == 1 and free_at(m, 1.2) == 1  # in front of the camera, short of the wall
    assert free_at(m, -0.5) == 0  # behind the camera: never looked at, though the ESDF says free there
    assert free_at(m, WALL_X) == 0 and free_at(m, 2.0) == 0  # the wall, and what it hides
    assert free_at(m, 0.8, 1.5) == 0  # outside the field of view
    assert float(g.distance[np.nonzero(g.observed_free)].min()) > 0  # no obstacle is ever free


def test_seen_free_is_forgotten_after_observed_free_s_and_moves_with_the_volume():
    m = mapper(observed_free_s=2.0, recentre_distance=0.1)
    integrate(m, 1.0)
    assert free_at(m, 0.8) == 1
    m.set_robot_position(np.array([0.6, 0.0, 0.0]))  # the volume shifts by 12 voxels
    assert m.shifts == 1 and free_at(m, 0.8) == 1 and free_at(m, -0.5) == 0
    integrate(m, 2.9, cam_x=1.2)  # 1.9 s later, looking at the wall from 0.3 m: x = 0.8 not seen again
    assert free_at(m, 0.8) == 1
    integrate(m, 3.1, cam_x=1.2)  # 2.1 s since x = 0.8 was seen
    assert free_at(m, 0.8) == 0


def test_the_layer_can_be_left_out():
    m = mapper(observed_free_s=0.0)
    integrate(m, 1.0)
    assert m.update_esdf().slice2d.observed_free is None
