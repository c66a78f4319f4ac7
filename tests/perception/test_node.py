"""The perception node over a real Zenoh router, in its own process: fed by a real simulator
process, and by a test client sending images/truth it pairs by stamp, hostile payloads included."""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import pytest

from riskfield.protocol import Image, NodeStatus, PerceptionFrame
from riskfield.protocol.messages import Header
from riskfield.testing import (
    Collector,
    ServiceProcess,
    client_session,
    hostile_payloads,
    put,
    wait_alive,
    wait_until,
)

SCENARIO = str(Path(__file__).parents[1] / "simulator" / "data" / "two_boxes.yaml")


def test_perception_with_the_simulator_publishes_current_frames(router_endpoint):
    robot = "t_per_sim"
    common = ["--robot", robot]
    with ServiceProcess("simulator", router_endpoint, [*common, "--set", f"scenario={SCENARIO}"]) as sim, \
            ServiceProcess("perception", router_endpoint, [*common, "--set", "status_period_s=0.3"]) as per, \
            client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/perception"), per.output
        frames = Collector(s, f"rf/{robot}/perception/frame", PerceptionFrame)
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        got = frames.wait(5, 30)
        f = got[-1]
        # compact: depth (float16) + intrinsics at the mapping's stride, from a truth at that stride
        assert f.points is None and f.depth.dtype == np.float16 and f.pixels == (48, 64) and f.keyframe_id == 0
        assert f.confidence.max() > 2.0 and f.intrinsics is not None
        assert len({g.header.stamp_ns for g in got}) == len(got)  # one message per frame, each its own
        assert {i.header.stamp_ns for i in images.items} >= {g.header.stamp_ns for g in got}  # image stamps kept
        assert per.stop(signal.SIGTERM) == 0 and sim.stop() == 0
        frames.close()
        images.close()


def _pair(stamp: int, h: int = 24, w: int = 32) -> tuple[Image, PerceptionFrame]:
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
    z = np.full((h, w), 2.0, np.float32)
    pts = np.stack([(uu - (w - 1) / 2) / 20 * z, (vv - (h - 1) / 2) / 20 * z, z], -1)
    labels = np.zeros((h, w), np.uint16)
    labels[:, w // 2:] = 126
    header = Header(stamp_ns=stamp, frame_id="camera")
    img = Image(header=header, encoding="rgb8", width=w, height=h, data=np.zeros((h, w, 3), np.uint8))
    truth = PerceptionFrame(header=Header(stamp_ns=stamp), T_WC=np.eye(4), points=pts, confidence=np.ones((h, w)),
                            labels=labels, keyframe_id=0)
    return img, truth


def test_perception_pairs_by_stamp_and_survives_hostile_input(router_endpoint):
    robot = "t_per_fuzz"
    args = ["--robot", robot, "--set", "status_period_s=0.3", "--set", "pair_timeout_s=0.3"]
    with ServiceProcess("perception", router_endpoint, args) as per, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/perception"), per.output
        frames = Collector(s, f"rf/{robot}/perception/frame", PerceptionFrame)
        status = Collector(s, f"rf/{robot}/status/perception", NodeStatus)
        img, truth = _pair(1000)
        # Hostile payloads on both subscribed keys, in a burst: what the latest-value queue of
        # camera/image skips is counted as dropped, the rest is decoded and rejected.
        bad_img, bad_truth = hostile_payloads(img, 150, seed=5), hostile_payloads(truth, 150, seed=6)
        for a, b in zip(bad_img, bad_truth, strict=True):
            put(s, f"rf/{robot}/camera/image", a)
            put(s, f"rf/{robot}/sim/truth", b)

        def stat(kind: str, key: str) -> int:
            return getattr(status.items[-1], kind).get(key, 0) if status.items else 0

        assert wait_until(lambda: stat("received", "camera/image") >= 150 and stat("received", "sim/truth") >= 150
                          and stat("invalid", "camera/image") + stat("dropped", "camera/image") >= 150, 15), \
            status.items[-1:]
        # Valid but inconsistent: a truth whose size is neither its image's nor every n-th pixel of
        # it is rejected, not a crash.
        img2, _ = _pair(2000)
        _, truth2 = _pair(2000, 10, 16)
        put(s, f"rf/{robot}/sim/truth", truth2)
        put(s, f"rf/{robot}/camera/image", img2)
        # camera/image is a latest-value queue: img2 is taken (and rejected) before the next one.
        assert wait_until(lambda: status.items[-1].extra.get("frames_rejected") == 1, 15), status.items[-1]
        # An image whose truth never comes is dropped after the timeout.
        put(s, f"rf/{robot}/camera/image", _pair(3000)[0])
        assert wait_until(lambda: status.items[-1].extra.get("unpaired_images", 0) >= 1, 15), status.items[-1]
        # Still serving: truth first, then the image, paired by stamp.
        put(s, f"rf/{robot}/sim/truth", truth)
        put(s, f"rf/{robot}/camera/image", img)
        out = frames.wait(1, 15)
        # a full-size truth: the frame goes out at the mapping's pixel stride (2), as depth
        assert len(out) == 1 and out[0].header.stamp_ns == 1000 and out[0].pixels == (12, 16)
        assert np.isfinite(out[0].pointmap()).all() and np.allclose(out[0].pointmap(), truth.points[::2, ::2],
                                                                     atol=0.2)
        # Image first, then its truth.
        img4, truth4 = _pair(4000)
        images_in = stat("received", "camera/image")
        put(s, f"rf/{robot}/camera/image", img4)
        assert wait_until(lambda: stat("received", "camera/image") > images_in, 15)  # it is at the node first
        put(s, f"rf/{robot}/sim/truth", truth4)
        assert frames.wait(2, 15)[-1].header.stamp_ns == 4000

        def settled() -> bool:
            st = status.items[-1] if status.items else None
            return bool(st and st.extra.get("frames_rejected") == 1 and st.extra.get("unpaired_images", 0) >= 1
                        and all(st.invalid.get(k, 0) >= 1 and st.invalid.get(k, 0) + st.dropped.get(k, 0) >= 150
                                for k in ("camera/image", "sim/truth")))

        assert wait_until(settled, 15), status.items[-1] if status.items else per.output
        assert status.items[-1].errors == 0 and per.alive()
        assert per.stop() == 0
        assert "could not process a frame" in per.output
        frames.close()
        status.close()


def test_mast3r_backend_refuses_to_start_with_a_clear_message(router_endpoint):
    args = ["--robot", "t_per_gpu", "--set", "geometry=mast3r", "--set", "labels=efficientvit"]
    with ServiceProcess("perception", router_endpoint, args) as per:
        assert wait_until(lambda: not per.alive(), 60)
        assert per.proc is not None and per.proc.returncode == 2
        out = per.output
        assert "perception backend unavailable" in out and "checkpoint" in out


def test_perception_aligns_a_wrongly_scaled_slam_to_odometry(router_endpoint):
    from riskfield.protocol import Alignment

    robot = "t_per_align"
    common = ["--robot", robot]
    args = [*common, "--set", "align=true", "--set", "slam_scale=1.15", "--set", "status_period_s=0.3"]
    with ServiceProcess("simulator", router_endpoint, [*common, "--set", f"scenario={SCENARIO}"]) as sim, \
            ServiceProcess("perception", router_endpoint, args) as per, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/perception"), per.output
        alignments = Collector(s, f"rf/{robot}/perception/alignment", Alignment)
        frames = Collector(s, f"rf/{robot}/perception/frame", PerceptionFrame)
        got = alignments.wait(5, 30)
        a = got[-1]
        # standing still: the floor plane and the camera's height undo SLAM's 1.15
        assert a.source == "floor" and not a.converged and a.scale == pytest.approx(1 / 1.15, rel=0.03)
        assert 0.01 < a.scale_sigma < 0.1  # the height's 2 mm at 0.1 m dominates
        f = frames.wait(5, 30)[-1]
        world = f.pointmap().reshape(-1, 3) @ f.T_WC[:3, :3].T + f.T_WC[:3, 3]
        floor = (f.labels.reshape(-1) == 3) & (f.confidence.reshape(-1) > 0)
        assert abs(float(np.median(world[floor, 2]))) < 0.01  # the floor back at z = 0 of odom
        assert per.stop(signal.SIGTERM) == 0 and sim.stop() == 0
        alignments.close()
        frames.close()
