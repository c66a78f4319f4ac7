"""The sim backend end to end on simulator renders: keyframes, matching by reprojection,
eq. (2) fusion reducing depth noise, vote fusion correcting label noise, both publish modes."""

from __future__ import annotations

import numpy as np
import pytest

from riskfield.protocol import PerceptionFrame, decode, encode
from riskfield.services.perception.degrade import DegradationConfig
from riskfield.services.perception.sim_backend import SimBackend, SimBackendConfig
from riskfield.services.simulator.scenario import load_scenario
from riskfield.services.simulator.world import World

SMALL = {"room": {"size": [6.0, 5.0]}, "camera": {"width": 128, "height": 96},
         "robot": {"type": "limo", "start": [-1.5, 0.0, 0.0]},
         "objects": [{"class": "animal", "position": [0.5, 0.3]}, {"class": "box", "position": [1.0, -0.8]},
                     {"class": "chair", "position": [2.0, 1.2]}]}


def truth_of(world: World, i: int = 0) -> tuple[PerceptionFrame, np.ndarray]:
    r = world.render()
    return PerceptionFrame(T_WC=r.T_WC, points=r.points, confidence=r.valid.astype(np.float32), labels=r.labels,
                           keyframe_id=i), r.points


def drive(world: World, v: float, w: float, dt: float) -> None:
    world.command(np.array([v, 0, 0]), np.array([0, 0, w]))
    world.advance(dt)


def test_fusion_reduces_depth_noise_and_keeps_the_keyframe():
    world = World(load_scenario(SMALL))
    cfg = SimBackendConfig(DegradationConfig(noise_a=0.01, noise_b=0.01, p_boundary=0, p_confuse=0, p_salt=0))
    b = SimBackend(cfg)
    truth, gt = truth_of(world)
    first = b.process(None, truth, 1)[0]
    err0 = np.abs(first.points[..., 2] - gt[..., 2])
    for i in range(8):  # standing still: every frame matches every keyframe pixel
        out = b.process(None, truth_of(world, i)[0], 2 + i)
    kf = out[0]
    assert kf.keyframe_id == 0 and b.n_keyframes == 1 and b.last_matches.overlap > 0.99
    err = np.abs(kf.points[..., 2] - gt[..., 2])
    assert np.median(err) < 0.5 * np.median(err0)  # nine observations averaged: ≈ 1/3 of the noise
    assert np.all(kf.confidence >= first.confidence)  # C accumulates (eq. 2)
    assert kf.header.stamp_ns == 9
    # The published frame survives the wire contract.
    again = decode(encode(kf), PerceptionFrame)
    np.testing.assert_array_equal(again.labels, kf.labels)


def test_matches_by_reprojection_agree_with_geometry():
    world = World(load_scenario(SMALL))
    b = SimBackend(SimBackendConfig(DegradationConfig.perfect()))
    t0, _ = truth_of(world)
    b.process(None, t0, 0)
    drive(world, 0.3, 0.2, 0.5)
    t1, gt1 = truth_of(world)
    b.process(None, t1, 1)
    m = b.last_matches
    assert m is not None and 0.6 < m.overlap < 1.0
    kf = b.keyframe
    T_CW = np.linalg.inv(t1.T_WC)
    world_pts = kf.world_true[m.valid_match_k]
    in_cam = world_pts @ T_CW[:3, :3].T + T_CW[:3, 3]
    matched = gt1.reshape(-1, 3)[m.idx_f2k[m.valid_match_k]]
    # The matched pixel sees (nearly) the same surface point: within a pixel's footprint.
    d = np.linalg.norm(in_cam - matched, axis=1)
    assert np.percentile(d, 95) < 0.05


def test_new_keyframe_when_the_view_changes():
    world = World(load_scenario(SMALL))
    b = SimBackend(SimBackendConfig(DegradationConfig.perfect(), kf_max_rotation_deg=20))
    b.process(None, truth_of(world)[0], 0)
    for i in range(10):
        drive(world, 0.0, 1.0, 0.1)  # turning on the spot
        b.process(None, truth_of(world, i)[0], i + 1)
    assert b.n_keyframes >= 3


def test_vote_fusion_repairs_label_noise():
    world = World(load_scenario(SMALL))
    noisy = DegradationConfig(noise_a=0, noise_b=0, boundary_px=2, p_boundary=0.5, p_confuse=0, p_salt=0.02)
    b = SimBackend(SimBackendConfig(noisy, seed=1))
    truth, _ = truth_of(world)
    gt_labels = truth.labels
    single = b.process(None, truth, 0)[0]
    acc0 = (single.labels == gt_labels).mean()
    for i in range(10):
        out = b.process(None, truth, i + 1)[0]
    acc = (out.labels == gt_labels).mean()
    assert acc0 < 0.99 and acc > acc0 and (1 - acc) < 0.5 * (1 - acc0)


def test_frame_mode_publishes_current_frame_with_fused_labels():
    world = World(load_scenario(SMALL))
    b = SimBackend(SimBackendConfig(DegradationConfig(drift_t=0.01), publish="frame"))
    t0, _ = truth_of(world)
    b.process(None, t0, 0)
    drive(world, 0.3, 0.0, 0.3)
    t1, _ = truth_of(world)
    f = b.process(None, t1, 1)[0]
    assert f.keyframe_id == 0
    assert not np.allclose(f.T_WC, t1.T_WC)  # drift is on
    assert np.linalg.norm(f.T_WC[:3, 3] - t1.T_WC[:3, 3]) < 0.1
    assert np.median(np.abs(f.points[..., 2] - t1.points[..., 2])) < 0.05  # this frame's own (noisy) depth


def test_rejects_truth_without_geometry():
    b = SimBackend()
    empty = PerceptionFrame(T_WC=np.eye(4), points=np.zeros((4, 4, 3)), confidence=np.zeros((4, 4)),
                            labels=np.zeros((4, 4), np.uint16), keyframe_id=0)
    with pytest.raises(ValueError):
        b.process(None, empty, 0)
    assert b.process(None, None, 0) == []


@pytest.mark.parametrize("publish", ["keyframe", "frame"])
def test_each_frame_publishes_its_own_pose_and_what_it_sees_now(publish: str) -> None:
    """The message of a tracked frame is that frame — its pose and its depth, also where an
    object appeared after the keyframe started (those pixels no longer match the keyframe) — never
    the keyframe's pointmap and pose under a new stamp."""
    world = World(load_scenario(SMALL))
    b = SimBackend(SimBackendConfig(DegradationConfig(noise_a=0, noise_b=0, p_boundary=0, p_confuse=0, p_salt=0),
                                    publish=publish))
    t0, _ = truth_of(world)
    first = b.process(None, t0, 1)[0]
    drive(world, 0.3, 0.0, 0.3)
    t1, pts = truth_of(world)
    # something steps in front of the camera between keyframes: a patch at half the depth
    near = pts.copy()
    near[30:60, 50:80] *= 0.5
    labels = t1.labels.copy()
    labels[30:60, 50:80] = 12  # person
    t1 = t1.model_copy(update={"points": near, "labels": labels})
    f = b.process(None, t1, 2)[0]
    assert f.keyframe_id == first.keyframe_id == 0  # still tracking the first keyframe
    assert f.header.stamp_ns == 2
    np.testing.assert_allclose(f.T_WC, t1.T_WC, atol=1e-9)  # this frame's pose, not the keyframe's
    assert not np.allclose(f.T_WC, first.T_WC, atol=1e-3)
    valid = t1.confidence > 0
    depth_err = np.abs(f.points[..., 2] - near[..., 2])
    assert depth_err[30:60, 50:80].max() < 1e-3  # the new object at this frame's depth
    # elsewhere the frame's own depth, or (``keyframe``) the fused keyframe point that a trusted match
    # put on this pixel: the same surface, off by the pixel's footprint on sloped faces
    assert np.percentile(depth_err[valid], 99) < (0.05 if publish == "keyframe" else 1e-3)
    assert (f.labels[30:60, 50:80] == 12).mean() > 0.9


def test_no_keyframe_outlives_what_it_shows() -> None:
    """``publish = updates``: a person in the keyframe walks away while the camera stands still (no
    new keyframe): the keyframe drops the pixels the frames now see through, and its next update
    carries the wall behind, not the person."""
    world = World(load_scenario(SMALL))
    b = SimBackend(SimBackendConfig(DegradationConfig(noise_a=0, noise_b=0, p_boundary=0, p_confuse=0, p_salt=0),
                                    publish="updates", update_every=2))
    t0, pts = truth_of(world)
    near = pts.copy()
    near[30:60, 50:80] *= 0.5  # a person in the keyframe
    first = b.process(None, t0.model_copy(update={"points": near}), 1)
    assert [f.kind for f in first] == ["keyframe_new"]
    assert (first[0].confidence[30:60, 50:80] > 0).all()
    out = []
    for i in range(2, 5):  # they left: the same view without them
        out += b.process(None, t0, i)
    assert b.n_keyframes == 1
    update = [f for f in out if f.kind == "keyframe_update"][-1]
    assert (update.confidence[30:60, 50:80] == 0).all()  # the ghost is out of the keyframe
    assert (update.confidence[:30] > 0).mean() > 0.9  # the rest stays
