"""The ``rgbd`` backend (depth + odometry) on simulator renders and over a real router with a real
simulator; unknown backends refused at start; the ``sim`` backend's drift-and-correction mode
driving a real Mapper, whose ESDF after the correction matches a map built from corrected poses."""

from __future__ import annotations

import math
import signal
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from riskfield.protocol import CERTAIN_CONFIDENCE, DepthImage, Image, PerceptionFrame, RobotState, ade20k
from riskfield.protocol.messages import Header
from riskfield.protocol.platforms import LIMO, CameraMount
from riskfield.services.geometry.transforms import transform_points
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.mapper import Mapper
from riskfield.services.perception.degrade import DegradationConfig
from riskfield.services.perception.node import PerceptionSettings
from riskfield.services.perception.rgbd_backend import RgbdBackend, RgbdConfig, back_project
from riskfield.services.perception.sim_backend import SimBackend, SimBackendConfig
from riskfield.services.simulator.scenario import load_scenario
from riskfield.services.simulator.world import World
from riskfield.testing import Collector, ServiceProcess, client_session, wait_alive, wait_until

SMALL = {"room": {"size": [6.0, 5.0]}, "camera": {"width": 128, "height": 96, "mount": {"pitch_deg": 10}},
         "robot": {"type": "limo", "start": [-1.5, 0.0, 0.0]},
         "objects": [{"class": "animal", "position": [0.5, 0.3]}, {"class": "box", "position": [1.0, -0.8]},
                     {"class": "chair", "position": [2.0, 1.2]}]}
SCENARIO = str(Path(__file__).parents[1] / "simulator" / "data" / "two_boxes.yaml")


def state_of(world: World, stamp: int) -> RobotState:
    st = world.state()
    return RobotState(header=Header(stamp_ns=stamp), position=tuple(st.position), orientation=tuple(st.orientation),
                      linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0))


@pytest.mark.parametrize("pitch", [0.0, 10.0, -25.0])
def test_extrinsic_matches_the_simulators_camera_mount(pitch: float) -> None:
    """Perception calibrated with a scenario's mount (its settings, as a user sets them) poses the camera
    where the simulator renders from: the scenario file's pitch and perception's rpy_deg are one angle."""
    mount = {"x": 0.12, "y": -0.03, "z": 0.2, "pitch_deg": pitch}
    yaw = 0.7
    world = World(load_scenario({"room": {"size": [4.0, 4.0]}, "camera": {"width": 16, "height": 12, "mount": mount},
                                 "robot": {"type": "limo", "start": [0.5, -0.2, yaw]}}))
    s = PerceptionSettings(geometry="rgbd", camera_position=(0.12, -0.03, 0.2), camera_rpy_deg=(0.0, pitch, 0.0))
    b = RgbdBackend(RgbdConfig(s.camera_mount()))
    b.on_state(state_of(world, 1))
    np.testing.assert_allclose(b.pose_at(1) @ b.T_BC, world.T_WC(), atol=1e-12)
    # Both sides share T_base_camera, so check the pose against the mount's meaning too: pitch > 0 looks down.
    p = math.radians(pitch)
    np.testing.assert_allclose(world.T_WC()[:3, 2], [math.cos(p) * math.cos(yaw), math.cos(p) * math.sin(yaw),
                                                     -math.sin(p)], atol=1e-12)


def test_rgbd_points_land_on_the_true_surface_with_one_class() -> None:
    world = World(load_scenario(SMALL))
    world.command(np.array([0.3, 0, 0]), np.array([0, 0, 0.4]))
    world.advance(1.0)
    r = world.render()
    cam = world.camera
    b = RgbdBackend(RgbdConfig(CameraMount(position=LIMO.camera.position, rpy_deg=(0.0, 10.0, 0.0)),
                               label=ade20k.index("wall")))
    b.on_state(state_of(world, 1000))
    img = Image(encoding="rgb8", width=cam.width, height=cam.height, data=r.rgb)
    depth = DepthImage(depth=r.depth, fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy)
    (f,) = b.process(img, depth, 1000)
    assert f.kind is None  # every RGB-D frame is an independent measurement
    np.testing.assert_allclose(f.T_WC, r.T_WC, atol=1e-9)
    np.testing.assert_allclose(f.points, r.points, atol=1e-5)
    ok = r.valid & (r.depth <= 6.0)
    world_pts = transform_points(f.T_WC, f.points[ok])
    true_pts = transform_points(r.T_WC, r.points[ok])
    assert np.abs(world_pts - true_pts).max() < 1e-4
    assert np.all(f.confidence[ok] == CERTAIN_CONFIDENCE) and np.all(f.confidence[~ok] == 0.0)
    assert np.all(f.labels == ade20k.index("wall"))
    # no state near the image's time: refused with a reason, not posed wrongly
    with pytest.raises(ValueError, match="nearest robot state"):
        b.process(img, depth, 1000 + 10**9)
    with pytest.raises(ValueError, match="depth is"):
        b.process(img, DepthImage(depth=r.depth[:-1], fx=1, fy=1, cx=0, cy=0), 1000)


def test_rgbd_labels_from_a_labeller() -> None:
    b = RgbdBackend(labeller=lambda rgb: np.full(rgb.shape[:2], 12, np.uint16))
    b.on_state(RobotState(header=Header(stamp_ns=5), position=(0, 0, 0), orientation=(0, 0, 0, 1),
                          linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0)))
    img = Image(encoding="rgb8", width=4, height=3, data=np.zeros((3, 4, 3), np.uint8))
    (f,) = b.process(img, DepthImage(depth=np.ones((3, 4), np.float32), fx=2, fy=2, cx=1.5, cy=1), 5)
    assert np.all(f.labels == 12)
    np.testing.assert_allclose(back_project(np.ones((3, 4)), 2, 2, 1.5, 1)[0, 0], [-0.75, -0.5, 1.0])


def test_unknown_backends_are_refused_in_one_line() -> None:
    for field, bad in (("geometry", "orbslam"), ("labels", "yolo"), ("rgbd_label", "not-a-class")):
        with pytest.raises(ValidationError) as err:
            PerceptionSettings(**{field: bad})
        assert bad in str(err.value)
    assert PerceptionSettings(geometry="rgbd").geometry == "rgbd"
    assert PerceptionSettings().efficientvit_model == "efficientvit-seg-l2-ade20k"


def test_unknown_backend_stops_the_node_with_a_clear_error(router_endpoint) -> None:
    args = ["--robot", "t_per_bad", "--set", "geometry=orbslam"]
    with ServiceProcess("perception", router_endpoint, args) as per:
        assert wait_until(lambda: not per.alive(), 60)
        assert per.proc is not None and per.proc.returncode != 0
        assert "unknown geometry backend 'orbslam'" in per.output and "Traceback" not in per.output


def test_the_stack_runs_with_rgbd_on_the_simulators_depth(router_endpoint) -> None:
    robot = "t_per_rgbd"
    common = ["--robot", robot]
    sim_args = [*common, "--set", f"scenario={SCENARIO}", "--set", "publish_depth=true"]
    per_args = [*common, "--set", "geometry=rgbd", "--set", "status_period_s=0.3"]
    with ServiceProcess("simulator", router_endpoint, sim_args) as sim, \
            ServiceProcess("perception", router_endpoint, per_args) as per, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/perception"), per.output
        depths = Collector(s, f"rf/{robot}/camera/depth", DepthImage)
        frames = Collector(s, f"rf/{robot}/perception/frame", PerceptionFrame)
        got = frames.wait(3, 30)
        f = got[-1]
        d = next((d for d in depths.items if d.header.stamp_ns == f.header.stamp_ns), None)
        assert d is not None and f.points.shape == (96, 128, 3)
        np.testing.assert_allclose(f.points[..., 2], np.where(d.depth <= 6.0, d.depth, 0.0), atol=1e-6)
        assert f.confidence.max() == CERTAIN_CONFIDENCE and np.all(f.labels == ade20k.index("wall"))
        assert per.stop(signal.SIGTERM) == 0 and sim.stop() == 0
        depths.close()
        frames.close()


# -- sim drift and correction → the mapper ---------------------------------------------------------


def test_drift_and_correction_reach_the_esdf(tmp_path: Path) -> None:
    world = World(load_scenario(SMALL))
    cfg = SimBackendConfig(DegradationConfig(noise_a=0, noise_b=0, p_boundary=0, p_confuse=0, p_salt=0, drift_t=0.03,
                                             drift_yaw=0.02),
                           publish="updates", kf_max_rotation_deg=12.0, correct_every=4, update_every=3, seed=3)
    b = SimBackend(cfg)
    mc = MapperConfig(output="3d", half_extent=(3.0, 3.0, 1.0), max_distance=1.5)
    m = Mapper(mc)
    m.set_robot_position(np.array([-1.5, 0.0, 0.0]))
    last: dict[int, PerceptionFrame] = {}
    kinds: list[str | None] = []
    drifted_before = None
    for i in range(80):
        world.command(np.array([0.0, 0, 0]), np.array([0, 0, 0.6]))  # turn on the spot: new keyframes
        world.advance(0.15)
        r = world.render()
        truth = PerceptionFrame(T_WC=r.T_WC, points=r.points, confidence=r.valid.astype(np.float32), labels=r.labels,
                                keyframe_id=i)
        for f in b.process(None, truth, i + 1):
            kinds.append(f.kind)
            if f.kind == "keyframe_update" and b.corrections == 2 and drifted_before is None:
                drifted_before = {k: v.T_WC.copy() for k, v in last.items()}
            m.integrate_frame(f)
            if f.kind != "tracking":
                last[f.keyframe_id] = f
        if b.corrections == 2:
            break  # right after the second loop closure
    assert b.corrections == 2 and {"keyframe_new", "keyframe_update", "tracking"} <= set(kinds)
    assert all(np.allclose(kf.T_WK, kf.T_WK_true) for kf in b.kept.values())  # every keyframe corrected
    assert drifted_before is not None and any(
        not np.allclose(drifted_before[k], last[k].T_WC) for k in drifted_before)  # and the correction moved some
    # The reference: every keyframe integrated once, at its corrected pose, with its last pointmap.
    ref = Mapper(mc)
    ref.set_robot_position(np.array([-1.5, 0.0, 0.0]))
    for k in sorted(last):
        ref.integrate_frame(last[k].model_copy(update={"kind": "keyframe_new"}))
    observed = ref.tsdf.weight > 0
    # The loop closure re-posed the world: the mapper's present layer (the last frames, in the
    # drifted frame of reference) was cleared, so the map is the keyframes' until the next frames.
    assert m.present.clears >= 1 and m.present.tsdf is not None and not (m.present.tsdf.weight > 0).any()
    ref.clear_present()
    d = m.update_esdf().grid3d.distance  # type: ignore[union-attr]
    d_ref = ref.update_esdf().grid3d.distance  # type: ignore[union-attr]
    assert np.abs(d - d_ref)[observed].max() <= mc.voxel_size
    # Without de-integration (each message integrated as an independent observation) the drift smears.
    smear = Mapper(mc)
    smear.set_robot_position(np.array([-1.5, 0.0, 0.0]))
    for k in sorted(last):
        smear.integrate_frame(last[k].model_copy(update={"kind": None}))
    for k, T in drifted_before.items():
        smear.integrate_frame(last[k].model_copy(update={"kind": None, "T_WC": T}))
    d_smear = smear.update_esdf().grid3d.distance  # type: ignore[union-attr]
    assert np.abs(d_smear - d_ref)[observed].max() > 2 * mc.voxel_size
