"""SLAM world → odometry: Umeyama's closed form, the floor plane's scale, the sliding-window estimator,
the sim backend's SLAM errors, and the perception node publishing aligned frames."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from riskfield.protocol import Alignment, PerceptionFrame, decode, encode
from riskfield.protocol.platforms import LIMO, CameraMount
from riskfield.services.geometry.camera import T_base_camera
from riskfield.services.geometry.transforms import pose_matrix
from riskfield.services.perception.alignment import (
    Aligner,
    AlignerConfig,
    FrameAligner,
    Similarity,
    align_frame,
    floor_scale,
    scale_given_rotation,
    umeyama,
)
from riskfield.services.perception.degrade import OdometrySlip, SlamErrorConfig, SlamWorld


def _random_similarity(seed: int, scale: float) -> Similarity:
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    return Similarity(scale, R, rng.uniform(-5, 5, 3))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), scale=st.floats(0.3, 3.0), n=st.integers(6, 60),
       noise=st.sampled_from([0.0, 1e-3, 5e-3]))
def test_umeyama_recovers_a_random_similarity_from_noisy_correspondences(seed: int, scale: float, n: int,
                                                                         noise: float) -> None:
    truth = _random_similarity(seed, scale)
    rng = np.random.default_rng(seed + 1)
    x = rng.uniform(-2, 2, (n, 3))
    y = truth.apply(x) + rng.normal(0.0, noise, (n, 3))
    est, err = umeyama(x, y)
    assert np.linalg.det(est.R) == pytest.approx(1.0)
    tol = 1e-9 if noise == 0 else 12 * noise / math.sqrt(n) / 0.5 + 1e-9  # σ/(√n·spread), spread ≥ ~0.5 m
    assert abs(est.scale / scale - 1.0) < tol + 1e-9
    assert np.abs(est.R - truth.R).max() < 10 * tol + 1e-9
    assert np.abs(est.apply(x) - truth.apply(x)).max() < 40 * noise + 1e-8
    # eq. 43: the closed-form error is the fit's mean squared residual
    assert err == pytest.approx(float(((est.apply(x) - y) ** 2).sum(axis=1).mean()), rel=1e-6, abs=1e-12)


def test_umeyama_planar_points_and_a_reflection_stay_a_rotation() -> None:
    # coplanar points (a ground robot's camera track): Σ_xy has rank 2, and the fit is still proper
    truth = _random_similarity(3, 1.2)
    rng = np.random.default_rng(0)
    x = np.c_[rng.uniform(-2, 2, (20, 2)), np.zeros(20)]
    est, err = umeyama(x, truth.apply(x))
    assert err < 1e-18 and est.scale == pytest.approx(1.2) and np.allclose(est.R, truth.R)
    # a mirrored pattern has no rotation: the best proper one, never a reflection
    mirrored = x * np.array([1.0, -1.0, 1.0])
    est, err = umeyama(np.c_[x[:, :2], rng.uniform(-1, 1, 20)], np.c_[mirrored[:, :2], rng.uniform(-1, 1, 20)])
    assert np.linalg.det(est.R) == pytest.approx(1.0) and err > 0
    with pytest.raises(ValueError, match="coincide"):
        umeyama(np.ones((4, 3)), np.zeros((4, 3)))


def test_a_line_needs_the_rotation_from_elsewhere() -> None:
    truth = Similarity(0.87, Rotation.from_euler("z", 0.3).as_matrix(), np.array([1.0, 2.0, 0.0]))
    x = np.c_[np.linspace(0, 2, 30), np.zeros(30), np.zeros(30)]
    est, err = scale_given_rotation(x, truth.apply(x), truth.R)
    assert est.scale == pytest.approx(0.87) and np.allclose(est.t, truth.t) and err < 1e-20


@settings(max_examples=30, deadline=None)
@given(scale=st.floats(0.7, 1.4), pitch=st.floats(-10, 20), height=st.floats(0.08, 0.5), seed=st.integers(0, 999))
def test_floor_scale_from_the_cameras_height(scale: float, pitch: float, height: float, seed: int) -> None:
    T_BC = T_base_camera(CameraMount(position=(0.15, 0.0, height), rpy_deg=(0.0, pitch, 0.0)))
    rng = np.random.default_rng(seed)
    floor_base = np.c_[rng.uniform(0.5, 3.0, 400), rng.uniform(-1, 1, 400), np.zeros(400)]
    cam = (floor_base - T_BC[:3, 3]) @ T_BC[:3, :3]  # base → camera
    up = T_BC[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    m = floor_scale(cam / scale + rng.normal(0, 1e-3, cam.shape), up, height, 0.002)
    assert m is not None and m.points == 200  # the nearer half
    assert m.scale == pytest.approx(scale, rel=0.01)
    assert 0.002 / height <= m.sigma < 0.002 / height + 0.01
    assert floor_scale(cam / scale, -up, height) is None  # upside down: nothing below the camera
    # a wall is not the floor
    wall = np.c_[rng.uniform(-1, 1, 400), rng.uniform(-1, 1, 400), np.full(400, 2.0)]
    assert floor_scale(wall, np.array([0.0, -1.0, 0.0]), height) is None
    assert floor_scale(cam[:10], up, height) is None


def _drive(aligner: Aligner, slam: Similarity, path: np.ndarray, T_BC: np.ndarray, noise: float,
           rng: np.random.Generator) -> None:
    inv = slam.inverse()
    for x, y, yaw in path:
        T_odom_cam = pose_matrix(x, y, 0.0, yaw) @ T_BC
        T_slam_cam = inv.pose(T_odom_cam)
        T_slam_cam[:3, 3] += rng.normal(0, noise, 3)
        aligner.add_pair(T_slam_cam, T_odom_cam)


def test_the_window_estimate_converges_on_a_straight_drive_and_a_curve() -> None:
    T_BC = T_base_camera(LIMO.camera)
    rng = np.random.default_rng(0)
    truth = Similarity(1 / 1.25, Rotation.from_euler("z", 0.2).as_matrix(), np.array([0.3, -0.2, 0.05]))
    a = Aligner(AlignerConfig())
    assert a.estimate().source == "none" and not math.isfinite(a.estimate().scale_sigma)
    straight = np.c_[np.linspace(0, 1.0, 60), np.zeros(60), np.zeros(60)]
    _drive(a, truth, straight[:1], T_BC, 0.0, rng)
    first = a.estimate()  # not moved, no floor: the rotation and the anchor, scale unknown
    assert first.source == "none" and first.scale_sigma == math.inf
    _drive(a, truth, straight[1:], T_BC, 0.003, rng)
    est = a.estimate()
    assert est.source == "motion" and est.converged and est.baseline > 0.9
    assert est.similarity.scale == pytest.approx(truth.scale, rel=0.01)
    assert np.allclose(est.similarity.R, truth.R, atol=1e-6)  # from the orientations: exact here
    assert est.residual < 0.01
    # a curve: the full Umeyama fit
    a = Aligner(AlignerConfig())
    t = np.linspace(0, 1.5, 80)
    _drive(a, truth, np.c_[np.sin(t), 1 - np.cos(t), t], T_BC, 0.003, rng)
    est = a.estimate()
    assert est.similarity.scale == pytest.approx(truth.scale, rel=0.01) and est.converged
    assert np.abs(est.similarity.R - truth.R).max() < 0.02


def test_floor_before_moving_then_fused_with_motion() -> None:
    a = Aligner(AlignerConfig(converged_sigma=0.01))
    a.add_pair(np.eye(4), np.eye(4))
    from riskfield.services.perception.alignment import FloorScale

    for _ in range(5):
        a.add_floor(FloorScale(0.8, 0.02, 500))
    est = a.estimate()
    assert est.source == "floor" and est.similarity.scale == pytest.approx(0.8) and not est.converged
    assert est.scale_sigma == pytest.approx(0.02)  # the height's error does not average away
    _drive(a, Similarity(0.8), np.c_[np.linspace(0.05, 1.0, 40), np.zeros(40), np.zeros(40)], np.eye(4), 0.001,
           np.random.default_rng(1))
    est = a.estimate()
    assert est.source == "fused" and est.scale_sigma < 0.01 and est.similarity.scale == pytest.approx(0.8, rel=0.005)


def test_the_window_slides_with_the_path() -> None:
    a = Aligner(AlignerConfig(window_m=1.0, min_step=0.05))
    for x in np.linspace(0, 3, 301):
        a.add_pair(pose_matrix(x, 0, 0, 0), pose_matrix(x, 0, 0, 0))
    spread = a.pairs[-1][2][0] - a.pairs[0][2][0]
    assert 0.95 <= spread <= 1.1 and len(a.pairs) <= 23  # 5 cm steps over ~1 m


def test_align_frame_moves_pose_and_scales_points_and_depth() -> None:
    sim = Similarity(1.25, Rotation.from_euler("z", 0.5).as_matrix(), np.array([1.0, 0.0, 0.0]))
    pts = np.random.default_rng(0).uniform(0.5, 2, (4, 5, 3)).astype(np.float32)
    T = pose_matrix(0.3, 0.2, 0.1, 0.4)
    f = PerceptionFrame(T_WC=T, points=pts, confidence=np.ones((4, 5), np.float32),
                        labels=np.zeros((4, 5), np.uint16), keyframe_id=0)
    g = align_frame(f, sim)
    world = (pts.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3])
    got = np.asarray(g.points, np.float64).reshape(-1, 3) @ g.T_WC[:3, :3].T + g.T_WC[:3, 3]
    assert np.allclose(got, sim.apply(world), atol=1e-5)
    assert np.allclose(g.T_WC[:3, :3] @ g.T_WC[:3, :3].T, np.eye(3))  # still rigid
    d = PerceptionFrame(T_WC=T, depth=np.full((4, 5), 2.0, np.float16), intrinsics=(5.0, 5.0, 2.0, 1.5),
                        confidence=np.ones((4, 5), np.float32), labels=np.zeros((4, 5), np.uint16), keyframe_id=0)
    assert np.asarray(align_frame(d, sim).depth).dtype == np.float16
    assert float(np.asarray(align_frame(d, sim).depth)[0, 0]) == pytest.approx(2.5)


def test_slam_world_and_odometry_slip_are_seeded_and_off_by_default() -> None:
    assert SlamErrorConfig().is_identity
    with pytest.raises(ValueError):
        SlamErrorConfig(slam_scale=0.0)
    with pytest.raises(ValueError):
        SlamErrorConfig(yaw_drift=-1.0)
    w = SlamWorld(SlamErrorConfig(1.15), seed=0)
    poses = [pose_matrix(x, 0.0, 0.1, 0.0) for x in np.linspace(0, 2, 21)]
    for T in poses:
        w.step(T)
    T_slam, k = w.to_slam(poses[-1])
    assert k == pytest.approx(1.15) and T_slam[0, 3] == pytest.approx(2 * 1.15)  # scaled about the first camera
    a, b = SlamWorld(SlamErrorConfig.bench(1.0), seed=4), SlamWorld(SlamErrorConfig.bench(1.0), seed=4)
    for T in poses:
        a.step(T)
        b.step(T)
    assert a.scale == b.scale != 1.0 and a.yaw == b.yaw != 0.0
    slip = OdometrySlip(0.02)
    out = [slip.pose(T) for T in poses]
    assert out[-1][0, 3] == pytest.approx(2 * 1.02) and out[-1][2, 3] == pytest.approx(0.1)


def test_frame_aligner_holds_frames_until_odometry_then_publishes_metric_ones() -> None:
    from riskfield.protocol import RobotState
    from riskfield.protocol.messages import Header

    T_BC = T_base_camera(CameraMount())
    fa = FrameAligner(T_BC, 0.002, AlignerConfig())
    s = 1.15
    h, w = 24, 32
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    K = (16.0, 16.0, 15.5, 11.5)
    # a camera 0.1 m above the floor looking ahead: rows below the horizon see the floor
    ray = np.stack([(u - K[2]) / K[0], (v - K[3]) / K[1], np.ones_like(u)], -1)
    depth = np.where(ray[..., 1] > 0.02, 0.1 / np.maximum(ray[..., 1], 1e-6), 0.0)
    pts = (ray * depth[..., None] / s).astype(np.float32)  # SLAM units
    labels = np.where(depth > 0, 3, 0).astype(np.uint16)
    frame = PerceptionFrame(header=Header(stamp_ns=10), T_WC=T_BC, points=pts,
                            confidence=(depth > 0).astype(np.float32), labels=labels, keyframe_id=0)
    assert fa.align([frame], 10) == []  # no odometry yet
    fa.odometry.on_state(RobotState(header=Header(stamp_ns=10), position=(0.0, 0.0, 0.0),
                                    orientation=(0.0, 0.0, 0.0, 1.0), linear_velocity=(0.0, 0.0, 0.0),
                                    angular_velocity=(0.0, 0.0, 0.0)))
    (out,) = fa.align([frame], 10)
    assert fa.last is not None and fa.last.source == "floor"
    assert fa.last.similarity.scale == pytest.approx(s, rel=0.01)
    msg = decode(encode(fa.last.message(10)), Alignment)
    assert msg.source == "floor" and msg.scale == pytest.approx(s, rel=0.01) and not msg.converged
    floor_z = (np.asarray(out.points).reshape(-1, 3) @ out.T_WC[:3, :3].T + out.T_WC[:3, 3])[labels.reshape(-1) > 0, 2]
    assert np.abs(floor_z).max() < 0.005  # the floor lands on z = 0 of odom


def test_re_posed_keyframes_leave_through_the_current_estimate_and_are_no_pairs() -> None:
    from riskfield.protocol import RobotState
    from riskfield.protocol.messages import Header

    T_BC = T_base_camera(LIMO.camera)
    fa = FrameAligner(T_BC, 0.002, AlignerConfig())
    truth = Similarity(0.8)  # SLAM's world is 1.25 × the metric one
    inv = truth.inverse()

    def frame(stamp: int, T: np.ndarray, kind: str | None) -> PerceptionFrame:
        return PerceptionFrame(header=Header(stamp_ns=stamp), T_WC=T, points=np.ones((2, 2, 3), np.float32),
                               confidence=np.ones((2, 2), np.float32), labels=np.zeros((2, 2), np.uint16),
                               keyframe_id=0, kind=kind)

    for i, x in enumerate(np.linspace(0.0, 1.0, 41)):
        stamp = 1000 + i
        fa.odometry.on_state(RobotState(header=Header(stamp_ns=stamp), position=(float(x), 0.0, 0.0),
                                        orientation=(0.0, 0.0, 0.0, 1.0), linear_velocity=(0.0, 0.0, 0.0),
                                        angular_velocity=(0.0, 0.0, 0.0)))
        out = fa.align([frame(stamp, inv.pose(pose_matrix(float(x), 0, 0, 0) @ T_BC), "tracking")], stamp)
    assert out and fa.last is not None and fa.last.similarity.scale == pytest.approx(0.8, rel=1e-3)
    pairs = len(fa.aligner.pairs)
    # a loop closure re-poses keyframe 0 (SLAM pose of the first camera): it leaves through the estimate
    kf = frame(999, inv.pose(T_BC), "keyframe_update")
    (moved,) = fa.align([kf], 2000)
    assert np.allclose(moved.T_WC, T_BC, atol=1e-3) and np.allclose(moved.points, 0.8, atol=1e-6)
    assert len(fa.aligner.pairs) == pairs  # a re-posed keyframe is no new correspondence
