"""Live-view drawing helpers, and the viewer node saving a Rerun recording of real traffic."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from riskfield.protocol import EsdfGrid, PerceptionFrame, RobotState, SafetyStatus, VelocityCommand
from riskfield.services.viewer.draw import esdf_slice_rgb, footprint, label_palette, pointmap_world


def _grid() -> EsdfGrid:
    d = np.linspace(-0.2, 1.0, 6 * 5 * 3, dtype=np.float32).reshape(6, 5, 3)
    g = np.zeros((6, 5, 3), np.uint8)
    g[:3] = 1
    return EsdfGrid(origin=(0, 0, 0), voxel_size=0.1, distance=d, risk_group=g, groups=["high", "mid", "low"],
                    max_distance=1.0, unknown_is_occupied=False)


def test_esdf_slice_image_orientation_and_colours():
    g = _grid()
    img = esdf_slice_rgb(g, z=0.1)
    assert img.shape == (5, 6, 3) and img.dtype == np.uint8  # rows are y, columns x
    inside = g.distance[:, :, 1] < 0
    assert np.all(img.transpose(1, 0, 2)[inside] == 20)
    far = np.unravel_index(np.argmax(g.distance[:, :, 1]), (6, 5))
    assert img[far[1], far[0], 1] > img[far[1], far[0], 0]  # far from obstacles: green


def test_pointmap_goes_to_world_and_drops_invalid():
    pts = np.zeros((4, 4, 3), np.float32)
    pts[..., 2] = 2.0
    pts[0, 0, 2] = -1.0  # behind the camera: invalid
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    f = PerceptionFrame(T_WC=T, points=pts, confidence=np.ones((4, 4), np.float32),
                        labels=np.full((4, 4), 12, np.uint16), keyframe_id=0)
    world, cols = pointmap_world(f, stride=1)
    assert world.shape == (15, 3) and np.allclose(world[:, 2], 5.0)
    assert np.all(cols == label_palette()[12])


def test_footprint_is_a_circle_with_a_heading_tick():
    s = RobotState(position=(1, 1, 0), orientation=(0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)),
                   linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0))
    fp = footprint(s, 0.2)
    assert np.allclose(np.hypot(fp[:-2, 0] - 1, fp[:-2, 1] - 1), 0.2)
    assert np.allclose(fp[-1], [1, 1.2, 0])


def test_viewer_node_saves_a_recording(router_endpoint, tmp_path):
    pytest.importorskip("rerun")
    from riskfield.services.runtime import Node
    from riskfield.services.viewer.node import ViewerSettings, setup
    from riskfield.testing import client_session, put, wait_until

    s = ViewerSettings(connect=[router_endpoint], robot="t_view", out=tmp_path)
    node = Node("viewer", s)
    view = setup(node, s)
    t = threading.Thread(target=node.run, daemon=True)
    t.start()
    try:
        with client_session(router_endpoint) as c:
            put(c, "rf/t_view/map/esdf", _grid())
            put(c, "rf/t_view/state", RobotState(position=(0, 0, 0), orientation=(0, 0, 0, 1),
                                                 linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0)))
            put(c, "rf/t_view/cmd/safe", VelocityCommand.zero("f"))
            put(c, "rf/t_view/safety/status", SafetyStatus(h=0.3, risk_group=1, intervening=True, fallback="stale_map",
                                                          solve_us=12.0, esdf_age_ms=5.0))
            assert wait_until(lambda: sum(node.status().received.values()) >= 4, 10)
    finally:
        node.stop()
        t.join(10)
        view.close()
    rrd = tmp_path / "view.rrd"
    assert rrd.is_file() and rrd.stat().st_size > 2000
