"""The Mapper end to end on rendered scenes: distances, margins, groups, rolling, rejection, hot reload."""

from __future__ import annotations

import numpy as np
import pytest

from riskfield.protocol import EsdfGrid, RiskConfig, ade20k, decode, encode
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, render
from riskfield.services.geometry.transforms import look_at, orbit
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.mapper import Mapper
from riskfield.services.mapping.pointmap import FrameRejected

V = 0.05


def build(scene: list, camera: PinholeCamera, output: str = "3d", risk: RiskConfig | None = None, **kw) -> Mapper:
    m = Mapper(MapperConfig(output=output, pixel_stride=1, max_distance=1.5, **kw), risk)
    m.set_robot_position(np.zeros(3))
    for T in orbit([1.2, 0.0, 0.3], n=5, radius=0.2, height=0.3):
        m.integrate(*render(scene, T, camera), T)
    return m


def line_in_front_of_person(n: int = 8) -> np.ndarray:
    # the person-box's front face is x = 0.8 for y in [-0.7, -0.4]; walk towards it along y = -0.55
    return np.stack([np.linspace(0.3, 0.55, n), np.full(n, -0.55), np.full(n, 0.3)], axis=1)


@pytest.mark.parametrize("output", ["3d", "2d"])
def test_distance_in_front_of_a_person_includes_its_margin(room: list, small_camera: PinholeCamera,
                                                           output: str) -> None:
    m = build(room, small_camera, output)
    up = m.update_esdf()
    assert up is not None
    grid = up.primary
    assert (grid.shape[2] == 1) == (output == "2d")
    assert grid.groups == ["high", "mid", "low"]
    p = line_in_front_of_person()
    ans = m.query(p)
    true = (0.8 - p[:, 0]) - 0.15
    assert ans.inside.all()
    assert np.all(ans.risk_group == 1)
    # conservative and within about a voxel (shell thickness + interpolation)
    assert np.all(ans.distance <= true + 0.5 * V)
    assert np.all(ans.distance >= true - 1.5 * V)
    # the gradient points away from the person (−x)
    assert np.all(ans.gradient[:, 0] < -0.5)


def test_wall_is_low_risk_without_margin_and_floor_is_free(room: list, small_camera: PinholeCamera) -> None:
    m = build(room, small_camera, "3d")
    m.update_esdf()
    p = np.array([[1.3, 0.0, 0.3], [1.35, 0.05, 0.9]])
    ans = m.query(p)
    assert np.all(ans.risk_group == 3)
    assert np.allclose(ans.distance, 1.5 - p[:, 0] - 0.5 * V, atol=V)
    # the floor is not an obstacle: just above it, far from everything else, the distance is large
    above_floor = m.query(np.array([[0.3, 0.0, 0.05]]))
    assert above_floor.distance[0] > 0.4


def test_margins_hot_reload_shifts_the_field_exactly(room: list, small_camera: PinholeCamera) -> None:
    m = build(room, small_camera, "3d")
    m.update_esdf()
    p = line_in_front_of_person()
    before = m.query(p).distance
    risk = RiskConfig()
    risk.groups[0].margin = 0.35
    m.set_risk_config(risk)
    assert m.dirty
    m.update_esdf()
    after = m.query(p)
    assert np.allclose(before - after.distance, 0.20, atol=1e-5)
    assert np.all(after.risk_group == 1)


def test_paper_dilation_variant_rounds_margins(room: list, small_camera: PinholeCamera) -> None:
    risk = RiskConfig()
    risk.groups[0].margin = 0.12  # rounds to 2 voxels = 0.10 m
    exact = build(room, small_camera, "3d", risk)
    dil = build(room, small_camera, "3d", risk, inflation="dilate")
    exact.update_esdf()
    dil.update_esdf()
    p = line_in_front_of_person()
    diff = dil.query(p).distance - exact.query(p).distance
    assert np.allclose(diff, 0.02, atol=0.004)


def test_ground_slice_ignores_obstacles_above_the_band(small_camera: PinholeCamera) -> None:
    lamp = ade20k.index("lamp")
    scene = [Box((0.6, -0.3, 1.0), (0.9, 0.3, 1.2), lamp)]  # hanging above the robot's band
    # No floor: nothing under the lamp is ever observed, which the default fill below obstacles
    # would claim (a lamp hanging over never-seen space); this test is about the band's slicing.
    m = Mapper(MapperConfig(output="both", pixel_stride=1, max_distance=1.0, unobserved_below_obstacle="free"))
    m.set_robot_position(np.zeros(3))
    for T in orbit([0.8, 0.0, 1.1], n=3, radius=0.2, height=0.3):
        m.integrate(*render(scene, T, small_camera), T)
    up = m.update_esdf()
    assert up is not None and up.slice2d is not None and up.grid3d is not None
    assert (up.grid3d.risk_group == 2).any()  # the lamp is in the 3-D map (mid risk) ...
    assert np.all(up.slice2d.distance == np.float32(1.0))  # ... but not in the robot's band
    assert up.slice2d.origin[2] == pytest.approx(0.35)
    # the published messages survive the codec
    g = decode(encode(up.slice2d), EsdfGrid)
    assert g.shape == (*m.config.shape[:2], 1)


def test_the_volume_rolls_with_the_robot_and_keeps_the_map(room: list, small_camera: PinholeCamera) -> None:
    m = build(room, small_camera, "3d")
    wall_point = np.array([1.5, 0.0, 0.3])
    m.update_esdf()
    d0 = m.query(wall_point[None]).distance[0]
    assert d0 < 0
    m.set_robot_position(np.array([0.8, 0.3, 0.0]))
    assert m.shifts == 1
    assert np.allclose(m.volume.centre, [0.8, 0.3, 0.0], atol=0.026)
    m.update_esdf()
    assert m.query(wall_point[None]).distance[0] == pytest.approx(d0, abs=1e-6)
    # a small move does not shift (hysteresis)
    m.set_robot_position(np.array([0.9, 0.3, 0.0]))
    assert m.shifts == 1


def test_bad_frames_are_rejected_and_change_nothing(room: list, small_camera: PinholeCamera) -> None:
    m = build(room, small_camera, "3d")
    weights = m.tsdf.weight.copy()
    T = look_at(np.array([0.0, 0.0, 0.3]), np.array([1.0, 0.0, 0.3]))
    pts, conf, lab = render(room, T, small_camera)
    scaled = T.copy()
    scaled[:3, :3] *= 1.2  # a Sim3 scale left in the pose
    mirrored = T.copy()
    mirrored[:3, 0] *= -1
    nan_pose = T.copy()
    nan_pose[0, 3] = np.nan
    bottom = T.copy()
    bottom[3, 0] = 0.5
    for bad in (scaled, mirrored, nan_pose, bottom, np.eye(3)):
        with pytest.raises(FrameRejected):
            m.integrate(pts, conf, lab, bad)
    with pytest.raises(FrameRejected, match="shapes differ"):
        m.integrate(pts, conf[:-1], lab, T)
    with pytest.raises(FrameRejected, match="over the limit"):
        Mapper(MapperConfig(max_pixels=100)).integrate(pts, conf, lab, T)
    with pytest.raises(FrameRejected, match="empty"):
        m.integrate(pts[:0], conf[:0], lab[:0], T)
    nan_pts = pts.copy()
    nan_pts[3, 3, 0] = np.nan
    with pytest.raises(FrameRejected, match="NaN"):
        m.integrate(nan_pts, conf, lab, T)
    assert np.array_equal(m.tsdf.weight, weights)


def test_query_before_any_map_is_outside(small_camera: PinholeCamera) -> None:
    m = Mapper(MapperConfig(unknown_is_occupied=True, max_distance=1.0))
    ans = m.query(np.zeros((3, 3)))
    assert not ans.inside.any() and np.all(ans.distance == -1.0)
    assert m.update_esdf() is None


def test_unknown_is_occupied_makes_unseen_space_an_obstacle(room: list, small_camera: PinholeCamera) -> None:
    m = build(room, small_camera, "3d", unknown_is_occupied=True)
    up = m.update_esdf()
    assert up is not None and up.primary.unknown_is_occupied
    behind_robot = m.query(np.array([[-1.5, 0.0, 0.3]]))  # never seen
    assert behind_robot.distance[0] < 0 and behind_robot.risk_group[0] == 3
