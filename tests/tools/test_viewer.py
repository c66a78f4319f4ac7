"""Live-view drawing helpers, and the viewer node saving a Rerun recording of real traffic that
the rerun SDK loads back with the entities, transforms and values the view promises."""

from __future__ import annotations

import math
import threading
import uuid

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import EsdfGrid, Header, Image, PerceptionFrame, RobotState, SafetyStatus, VelocityCommand
from riskfield.protocol.ade20k import CLASSES, index
from riskfield.services.viewer.draw import (
    OnChange,
    ade20k_classes,
    camera_in_robot,
    esdf_slice,
    footprint,
    intrinsics_from_pointmap,
    map_bounds,
    pointmap_world,
    robot_pose,
)


def _asymmetric_grid() -> EsdfGrid:
    """nx = 6, ny = 4, nz = 3 at 0.1 m from (1, -2, 0); one obstacle cell at x index 4, y index 1
    (so a transposed or flipped image puts it elsewhere), distance = Euclidean to it minus 0.05."""
    nx, ny, nz, vs = 6, 4, 3, 0.1
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    d2 = np.hypot(i - 4, j - 1) * vs - 0.05
    d = np.repeat(d2[:, :, None], nz, axis=2).astype(np.float32)
    d[:, :, 0] += 1.0  # the z = 0 layer differs: the slice must be the one at z_slice
    g = np.zeros((nx, ny, nz), np.uint8)
    g[d < 0] = 1
    return EsdfGrid(origin=(1.0, -2.0, 0.0), voxel_size=vs, distance=d, risk_group=g, groups=["high", "mid", "low"],
                    max_distance=1.0, unknown_is_occupied=False)


def _drawn_at(corner, cell: float, height: int, row: int, col: int) -> np.ndarray:
    """Where Rerun's GridMap draws the centre of image pixel (row, col): the first row at the top,
    grid y = height·cell, rows running along −y (rerun-io/rerun, re_view_spatial grid_map.rs)."""
    return np.array(corner[:2]) + np.array([(col + 0.5) * cell, (height - row - 0.5) * cell])


def test_esdf_slice_grid_map_draws_each_distance_at_its_map_position():
    g = _asymmetric_grid()
    d, corner = esdf_slice(g, z=0.1)
    assert d.shape == (4, 6) and d.dtype == np.float32  # rows are y, columns x
    # the lower-left corner is the corner of cell (0, 0), whose centre is the origin
    np.testing.assert_allclose(corner, (0.95, -2.05, 0.1))
    r, c = np.unravel_index(np.argmin(d), d.shape)
    # the obstacle (x index 4, y index 1) is drawn at its map position, not mirrored or transposed
    np.testing.assert_allclose(_drawn_at(corner, g.voxel_size, d.shape[0], r, c), (1.4, -1.9))
    for (row, col), value in np.ndenumerate(d):  # every pixel: the distance of the cell drawn there
        x, y = _drawn_at(corner, g.voxel_size, d.shape[0], row, col)
        i, j = round((x - g.origin[0]) / g.voxel_size), round((y - g.origin[1]) / g.voxel_size)
        assert value == g.distance[i, j, 1]  # metres, from the slice at z = 0.1
    lo, size = map_bounds(g)
    np.testing.assert_allclose(lo, (0.95, -2.05, -0.05)) and np.testing.assert_allclose(size, (0.6, 0.4, 0.3))


def test_pointmap_goes_to_world_with_class_ids_and_drops_invalid():
    pts = np.zeros((4, 4, 3), np.float32)
    pts[..., 2] = 2.0
    pts[0, 0, 2] = -1.0  # behind the camera: invalid
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    f = PerceptionFrame(T_WC=T, points=pts, confidence=np.ones((4, 4), np.float32),
                        labels=np.full((4, 4), index("person"), np.uint16), keyframe_id=0)
    world, ids = pointmap_world(f, stride=1)
    assert world.shape == (15, 3) and np.allclose(world[:, 2], 5.0)
    assert np.all(ids == 12)
    classes = ade20k_classes()
    assert len(classes) == len(CLASSES) and classes[12][:2] == (12, "person")


def test_footprint_is_a_circle_around_the_robot_frame_origin_with_a_heading_tick():
    fp = footprint(0.2)
    assert np.allclose(np.hypot(fp[:-2, 0], fp[:-2, 1]), 0.2) and np.allclose(fp[:, 2], 0)
    assert np.allclose(fp[-1], [0.2, 0, 0])  # along the robot's +x: the transform turns it with the robot


def test_camera_pose_in_the_robot_frame():
    s = RobotState(position=(1, 2, 0), orientation=(0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)),
                   linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0))
    T_WR = robot_pose(s)
    np.testing.assert_allclose(T_WR[:3, 0], [0, 1, 0], atol=1e-12)  # yaw 90°: robot x is world y
    T_RC = np.eye(4)
    T_RC[:3, 3] = [0.15, 0, 0.1]
    np.testing.assert_allclose(camera_in_robot(T_WR @ T_RC, T_WR), T_RC, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(fx=st.floats(50, 800), fy=st.floats(50, 800), cx=st.floats(5, 60), cy=st.floats(5, 40),
       depth=st.floats(0.5, 8.0))
def test_intrinsics_are_recovered_from_a_pinhole_pointmap(fx, fy, cx, cy, depth):
    h, w = 48, 64
    v, u = np.mgrid[0:h, 0:w].astype(float)
    z = depth + 0.1 * u  # any positive depth profile
    pts = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=-1).astype(np.float32)
    got = intrinsics_from_pointmap(pts)
    assert got is not None
    np.testing.assert_allclose(got, (fx, fy, cx, cy), rtol=1e-3, atol=1e-2)


def test_intrinsics_need_a_spread_of_valid_pixels():
    assert intrinsics_from_pointmap(np.full((4, 4, 3), np.nan, np.float32)) is None
    assert intrinsics_from_pointmap(np.tile(np.array([0.0, 0.0, 1.0], np.float32), (4, 4, 1))) is None


def test_on_change_passes_each_new_value_once():
    seen = OnChange()
    assert [seen(v) for v in ["no_ref", "no_ref", "no_ref", None, None, "no_ref", "stale_map"]] == [
        True, False, False, True, False, True, True]


# -- the node, over Zenoh, and its .rrd read back with the rerun SDK ------------------------------

def _state(x: float = 0.5) -> RobotState:
    return RobotState(position=(x, 0, 0), orientation=(0, 0, 0, 1), linear_velocity=(0, 0, 0),
                      angular_velocity=(0, 0, 0))


def _frame() -> PerceptionFrame:
    h, w, f = 12, 16, 8.0
    v, u = np.mgrid[0:h, 0:w].astype(float)
    z = np.full((h, w), 2.0)
    pts = np.stack([(u - 7.5) / f * z, (v - 5.5) / f * z, z], axis=-1).astype(np.float32)
    T_WC = robot_pose(_state())
    T_RC = np.eye(4)
    T_RC[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    T_RC[:3, 3] = [0.15, 0, 0.1]
    labels = np.full((h, w), index("wall"), np.uint16)
    labels[:, : w // 2] = index("person")
    return PerceptionFrame(T_WC=T_WC @ T_RC, points=pts, confidence=np.ones((h, w), np.float32), labels=labels,
                           keyframe_id=0)


def _chunks(rrd):
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd)
    (entry,) = reader.recordings()
    by_entity: dict[str, list] = {}
    for c in reader.stream():
        by_entity.setdefault(c.entity_path, []).append(c.to_record_batch())
    return entry, by_entity


def _column(batches, name):
    cols = [b.column(b.schema.names.index(name)) for b in batches if name in b.schema.names]
    assert cols, f"no column {name}"
    return [row for col in cols for row in col.to_pylist()]


def test_viewer_node_saves_a_recording_rerun_loads_back(router_endpoint, tmp_path):
    pytest.importorskip("rerun")
    from riskfield.services.runtime import Node
    from riskfield.services.viewer.node import APPLICATION_ID, ViewerSettings, setup
    from riskfield.testing import client_session, put, wait_until

    s = ViewerSettings(connect=[router_endpoint], robot="t_view", out=tmp_path)
    node = Node("viewer", s)
    view = setup(node, s)
    t = threading.Thread(target=node.run, daemon=True)
    t.start()
    grid = _asymmetric_grid()
    statuses = ["no_ref"] * 20 + [None] * 5 + ["no_ref"] * 5
    try:
        with client_session(router_endpoint) as c:
            # Repeated until drawn: the first put may reach the router before the viewer's
            # subscription does (Zenoh matches asynchronously); a repeated state changes nothing.
            assert wait_until(lambda: (put(c, "rf/t_view/state", _state()), view.drawn["state"] >= 1)[1], 10,
                              period_s=0.1)
            put(c, "rf/t_view/map/esdf", grid)
            put(c, "rf/t_view/perception/frame", _frame())
            rgb = np.zeros((24, 32, 3), np.uint8)
            rgb[:, :16, 0] = 255
            t0 = 1_000_000_000_000
            for n, dt in enumerate((0.0, 0.1, 0.6), start=1):  # the second is within camera_period_s: not drawn
                put(c, "rf/t_view/camera/image", Image(header=Header(stamp_ns=t0 + int(dt * 1e9)), encoding="rgb8",
                                                       width=32, height=24, data=rgb))
                assert wait_until(lambda n=n: view.drawn["image"] >= n, 10)
            put(c, "rf/t_view/cmd/safe", VelocityCommand.zero("f"))
            for fb in statuses:
                put(c, "rf/t_view/safety/status", SafetyStatus(h=0.3, risk_group=1, intervening=fb is not None,
                                                              fallback=fb, solve_us=12.0, esdf_age_ms=5.0))
            assert wait_until(lambda: view.drawn["status"] >= len(statuses) and view.drawn["esdf"] >= 1
                              and view.drawn["frame"] >= 1 and view.drawn["image"] >= 1, 20), view.drawn
    finally:
        node.stop()
        t.join(10)
        view.close()
    rrd = tmp_path / "view.rrd"
    entry, ents = _chunks(rrd)

    # a fresh recording per run, named after the robot, which is also a recording property
    assert entry.application_id == APPLICATION_ID
    assert str(uuid.UUID(entry.recording_id)) == entry.recording_id == view.recording_id
    assert _column(ents["/__properties/robot"], "robot") == [["t_view"]]

    for path in ("/world", "/world/robot", "/world/robot/footprint", "/world/robot/camera",
                 "/world/robot/camera/image", "/world/esdf", "/world/pointmap"):
        assert path in ents, sorted(ents)
    names = lambda p: {n for b in ents[p] for n in b.schema.names}  # noqa: E731
    assert {"Transform3D:translation", "Transform3D:quaternion"} <= names("/world/robot")
    assert "LineStrips3D:strips" in names("/world/robot/footprint")  # a child: moves with world/robot
    assert {"Pinhole:image_from_camera", "Pinhole:resolution", "Transform3D:mat3x3"} <= names("/world/robot/camera")
    assert "EncodedImage:blob" in names("/world/robot/camera/image")  # JPEG, to keep view.rrd small
    assert len(_column(ents["/world/robot/camera/image"], "EncodedImage:blob")) == 2  # one per camera_period_s
    assert {"AnnotationContext:context", "Points3D:class_ids"} <= names("/world/pointmap")

    # the pinhole fitted from the pointmap (f = 8 px at 16 px wide), scaled to the 32 px image
    K = np.array(_column(ents["/world/robot/camera"], "Pinhole:image_from_camera")[-1][0]).reshape(3, 3).T
    np.testing.assert_allclose(K[0, 0], 16.0, rtol=1e-3) and np.testing.assert_allclose(K[0, 2], 15.5, atol=1e-2)
    # the camera pose in the robot frame, from T_WC and the robot's pose
    t_rc = _column(ents["/world/robot/camera"], "Transform3D:translation")[-1][0]
    np.testing.assert_allclose(t_rc, [0.15, 0, 0.1], atol=1e-6)

    # class ids on the pointmap, names in the annotation context
    ids = np.concatenate([np.asarray(r) for r in _column(ents["/world/pointmap"], "Points3D:class_ids") if r])
    assert set(ids.tolist()) == {index("person"), index("wall")}
    (ctx,) = _column(ents["/world/pointmap"], "AnnotationContext:context")[0]
    labels = {e["class_id"]: e["class_description"]["info"]["label"] for e in ctx}
    assert labels[12] == "person" and len(labels) == len(CLASSES)

    # the ESDF slice: distances in metres, lower-left corner at origin − s/2
    fmt = _column(ents["/world/esdf"], "GridMap:format")[-1][0]
    data = _column(ents["/world/esdf"], "GridMap:data")[-1][0]
    d = np.frombuffer(bytes(data), np.float32).reshape(fmt["height"], fmt["width"])
    np.testing.assert_array_equal(d, grid.distance[:, :, 1].T[::-1])  # the top row is the highest y
    np.testing.assert_allclose(_column(ents["/world/esdf"], "GridMap:translation")[-1][0], (0.95, -2.05, 0.1),
                               atol=1e-6)
    assert _column(ents["/world/esdf"], "GridMap:cell_size")[-1][0] == pytest.approx(0.1)

    # text logs only when the fallback reason changes: braking, normal, braking again
    texts = [r[0] for r in _column(ents["/safety/log"], "TextLog:text")]
    assert texts == ["braking: no_ref", "filtering normally", "braking: no_ref"]
