"""The floor seen free (``free_floor``, ``EsdfGrid.observed_free``): only where rays crossed it,
never an obstacle, forgotten after ``observed_free_s``, kept in place when the volume moves."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.free_floor import mark_free_by_arrays
from riskfield.protocol import ade20k
from riskfield.services.geometry.transforms import quat_to_matrix
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.free_floor import _mark_free
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


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rows=st.integers(1, 24), cols=st.integers(1, 32), stride=st.integers(1, 3),
       voxel=st.sampled_from([0.05, 0.1]), top=st.floats(0.1, 1.0))
def test_the_compiled_rays_mark_the_cells_the_array_sampling_marks(seed: int, rows: int, cols: int, stride: int,
                                                                   voxel: float, top: float) -> None:
    """``_mark_free`` sample by sample equals the same sampling done on whole arrays (the oracle),
    for any pose, bad pixels (NaN, low confidence, too near or far) included."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(0.0, 2.0, (rows, cols, 3)).astype(np.float32)
    pts[rng.random(pts.shape[:2]) < 0.05] = np.nan
    conf = rng.uniform(0.0, 2.0, pts.shape[:2]).astype(np.float32)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = quat_to_matrix(rng.normal(size=4) + 1e-3), rng.uniform(-1.0, 1.0, 3) * (1.0, 1.0, 0.3)
    limits = np.array([0.5, rng.uniform(0.0, 1.5), rng.uniform(1.5, 5.0), rng.uniform(0.0, 0.3),
                       rng.uniform(-0.3, 0.0), top])
    origin = rng.integers(-30, -10, 2)
    seen = [np.full((40, 40, 1), -7, np.int32) for _ in range(2)]
    p, c = pts[::stride, ::stride], conf[::stride, ::stride]
    n = _mark_free(p, c, np.ascontiguousarray(T[:3, :3]), T[:3, 3].copy(), limits, voxel, origin, seen[0], 1234)
    assert n == mark_free_by_arrays(p, c, T, limits, voxel, origin, seen[1], 1234)
    np.testing.assert_array_equal(seen[0], seen[1])
