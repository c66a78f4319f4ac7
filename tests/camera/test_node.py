"""`riskfield run camera` as a real process over a real Zenoh router: a real encoded video, image
folders and a calibration file played onto `camera/image`, checked frame by frame from the pixels."""

from __future__ import annotations

import io
import threading
import time
from pathlib import Path

import av
import numpy as np
import pytest
import zenoh
from camera.media import frame_pixels, pillow_jpeg, read_index, strip_huffman_tables, write_video
from PIL import Image as PILImage

from riskfield.protocol import Image, PerceptionFrame, decode
from riskfield.services.camera.calibration import parse_calibration
from riskfield.services.camera.undistort import Undistorter
from riskfield.testing import Collector, ServiceProcess, StatusWatch, client_session, put, wait_until

FPS = 20
N = 30


def pixels(image: Image) -> np.ndarray:
    if image.encoding == "rgb8":
        return np.asarray(image.data)
    return np.asarray(PILImage.open(io.BytesIO(image.data)).convert("RGB"))


class WallCollector:
    """Every image on a key with its wall-clock arrival time (the stamps are wall clock too)."""

    def __init__(self, session: zenoh.Session, key: str):
        self.items: list[tuple[int, Image]] = []
        self._lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            arrival = time.time_ns()
            msg = decode(sample.payload.to_bytes(), Image)
            with self._lock:
                self.items.append((arrival, msg))

        self._sub = session.declare_subscriber(key, on_sample)

    def wait(self, n: int, timeout_s: float = 20.0) -> list[tuple[int, Image]]:
        if not wait_until(lambda: len(self.items) >= n, timeout_s):
            raise TimeoutError(f"got {len(self.items)} of {n} images in {timeout_s} s")
        with self._lock:
            return list(self.items)

    def close(self) -> None:
        self._sub.undeclare()


def _camera(robot: str, endpoint: str, *settings: str) -> ServiceProcess:
    args = ["--robot", robot, "--set", "status_period_s=0.2"]
    for s in settings:
        args += ["--set", s]
    return ServiceProcess("camera", endpoint, args)


def test_a_video_file_plays_every_frame_in_order_at_its_rate_with_capture_stamps(router_endpoint, tmp_path):
    robot = "t_cam_video"
    video = write_video(tmp_path / "indexed.mp4", N, FPS)
    with client_session(router_endpoint) as s:
        # Subscribed before the camera starts: a recording plays once someone listens (wait_subscriber).
        images = WallCollector(s, f"rf/{robot}/camera/image")
        status = StatusWatch(s, f"rf/{robot}/status/camera")
        with _camera(robot, router_endpoint, f"source={video}", "encoding=jpeg") as cam:
            st = status.wait(lambda st: st.extra.get("eof") == 1 and st.extra.get("frames_published")
                             == N - st.extra.get("frames_dropped", 0), 30)
            got = images.wait(int(st.extra["frames_published"]))
            assert cam.stop() == 0, cam.output
        images.close()
        status.close()
    arrivals = [a for a, _ in got]
    msgs = [m for _, m in got]
    index = [read_index(pixels(m)) for m in msgs]
    # Every frame, in order — or, when this machine stalled the node for a frame period (the slot
    # holds one frame, by design), exactly the frames the node counted as dropped are missing.
    dropped = int(st.extra["frames_dropped"])
    assert index == sorted(set(index)) and len(index) + dropped == N, (index, st.extra, cam.output)
    assert dropped <= 2, (index, st.extra)
    assert all(m.encoding == "jpeg" and (m.width, m.height) == (96, 64) for m in msgs)
    assert all(m.header.frame_id == "camera" and m.intrinsics is None for m in msgs)
    assert [m.header.seq for m in msgs] == list(range(len(msgs)))
    stamps = np.array([m.header.stamp_ns for m in msgs])
    # The capture stamp is the container time after the start of playback: frame i at i / FPS.
    np.testing.assert_allclose(stamps - stamps[0], (np.array(index) - index[0]) * 1e9 / FPS, atol=2_000)
    # Real time: no frame goes out before the moment its stamp names.
    assert all(a >= t for a, t in zip(arrivals, stamps, strict=True))
    assert st.extra["frames_captured"] == N
    assert st.extra["frames_rejected"] == 0 and st.extra["capture_errors"] == 0


@pytest.mark.slow
def test_a_video_file_plays_in_real_time(router_endpoint, tmp_path):
    """The wall-clock side: every frame arrives, at the file's 20 Hz (within 15 %), on a machine
    that does not stall the node for a frame period."""
    robot = "t_cam_rate"
    video = write_video(tmp_path / "indexed.mp4", 40, FPS)
    with client_session(router_endpoint) as s:
        images = WallCollector(s, f"rf/{robot}/camera/image")
        with _camera(robot, router_endpoint, f"source={video}"):
            got = images.wait(40)
        images.close()
    span_s = (got[-1][0] - got[0][0]) / 1e9
    assert 39 / FPS * 0.85 <= span_s <= 39 / FPS * 1.15
    lateness_ms = np.array([(a - m.header.stamp_ns) / 1e6 for a, m in got])
    assert np.median(lateness_ms) < 50


def test_pace_perception_sends_the_next_frame_when_perception_answered(router_endpoint, tmp_path):
    """As fast as perception takes it: the test plays perception, answering each image with a frame
    of the same stamp; every frame comes, in order, none dropped, none waiting for a timeout."""
    robot = "t_cam_pace"
    codec = "libx264" if "libx264" in av.codecs_available else "mpeg4"  # H.264 in Matroska where the wheel has it
    video = write_video(tmp_path / "indexed.mkv", N, FPS, codec=codec)
    with client_session(router_endpoint) as s:
        answered: list[int] = []
        frame_key = f"rf/{robot}/perception/frame"

        def answer(sample: zenoh.Sample) -> None:
            image = decode(sample.payload.to_bytes(), Image)
            answered.append(read_index(pixels(image)))
            reply = PerceptionFrame(T_WC=np.eye(4), points=np.zeros((1, 1, 3), np.float32),
                                    confidence=np.ones((1, 1), np.float32), labels=np.zeros((1, 1), np.uint16),
                                    keyframe_id=0)
            reply.header.stamp_ns = image.header.stamp_ns
            put(s, frame_key, reply)

        sub = s.declare_subscriber(f"rf/{robot}/camera/image", answer)
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        status = StatusWatch(s, f"rf/{robot}/status/camera")
        with _camera(robot, router_endpoint, f"source={video}", "pace=perception", "ack_timeout_s=30",
                     "encoding=rgb8") as cam:
            msgs = images.wait(N, 30)
            st = status.wait(lambda st: st.extra.get("eof") == 1, 30)
            assert cam.stop() == 0, cam.output
        sub.undeclare()
        images.close()
        status.close()
    assert [read_index(pixels(m)) for m in msgs] == list(range(N)), cam.output
    assert answered == list(range(N))
    stamps = [m.header.stamp_ns for m in msgs]
    assert all(np.diff(stamps) > 0)
    assert st.extra["frames_dropped"] == 0 and st.extra["ack_timeouts"] == 0 and st.extra["frames_published"] == N


def test_an_image_folder_loops_with_increasing_stamps_and_jpeg_files_pass_through(router_endpoint, tmp_path):
    robot = "t_cam_folder"
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(3):  # natural order: frame2 before frame10; PNG decoded, JPEG kept as it is
        name = folder / (f"frame{i * 8}.jpg" if i == 1 else f"frame{i * 8}.png")
        PILImage.fromarray(frame_pixels(i)).save(name, quality=95)
    (folder / "notes.txt").write_text("not an image")
    jpeg_bytes = (folder / "frame8.jpg").read_bytes()
    with client_session(router_endpoint) as s:
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        status = StatusWatch(s, f"rf/{robot}/status/camera")
        with _camera(robot, router_endpoint, f"source={folder}", "loop=true", "rate_hz=20") as cam:
            msgs = images.wait(9, 20)
            st = status.wait(lambda st: st.extra.get("loops", 0) >= 2)
            assert cam.stop() == 0, cam.output
        images.close()
        status.close()
    # Frame k of the endless sequence is image k % 3, stamped k / 20 s after the first (a frame the
    # node dropped, counted, leaves a gap): the loop's stamps continue where the previous pass ended.
    stamps = np.array([m.header.stamp_ns for m in msgs])
    position = (stamps - stamps[0]) * 20 / 1e9
    np.testing.assert_allclose(position, np.round(position), atol=1e-4)
    k = np.round(position).astype(int)
    assert list(k) == sorted(set(k)) and k[-1] >= 6, k
    assert [read_index(pixels(m)) for m in msgs] == [int(i) % 3 for i in k], cam.output
    assert all(m.data == jpeg_bytes for m, i in zip(msgs, k, strict=True) if i % 3 == 1)  # the JPEG, untouched
    assert st.extra["frames_rejected"] == 0


ROS_INFO = """\
image_width: 96
image_height: 64
camera_name: test_cam
camera_matrix:
  rows: 3
  cols: 3
  data: [80.0, 0.0, 47.5, 0.0, 80.0, 31.5, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.2, 0.05, 0.001, -0.001, 0.0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [70.0, 0.0, 47.0, 0.0, 0.0, 70.0, 32.0, 0.0, 0.0, 0.0, 1.0, 0.0]
"""


def test_a_calibrated_camera_sends_undistorted_images_with_their_intrinsics(router_endpoint, tmp_path):
    robot = "t_cam_calib"
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(0)
    raw = rng.integers(0, 256, (64, 96, 3), dtype=np.uint8)
    PILImage.fromarray(raw).save(folder / "0.png")
    calib_file = tmp_path / "camera_info.yaml"
    calib_file.write_text(ROS_INFO)
    with client_session(router_endpoint) as s:
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        with _camera(robot, router_endpoint, f"source={folder}", f"calibration={calib_file}", "encoding=rgb8") as cam:
            msg = images.wait(1, 20)[0]
            assert cam.stop() == 0, cam.output
        images.close()
    assert msg.intrinsics == (70.0, 70.0, 47.0, 32.0)  # the rectified image's P, not K
    expected = Undistorter(parse_calibration(ROS_INFO))(raw)
    np.testing.assert_array_equal(np.asarray(msg.data), expected)
    assert not np.array_equal(np.asarray(msg.data), raw)


def test_a_missing_source_or_bad_calibration_fails_at_start_in_one_line(router_endpoint, tmp_path):
    missing = ServiceProcess("camera", router_endpoint, ["--set", f"source={tmp_path / 'nope.mp4'}"])
    with missing:
        assert wait_until(lambda: not missing.alive(), 30)
    assert missing.proc is not None and missing.proc.returncode == 2
    assert "nope.mp4 does not exist" in missing.output
    bad = tmp_path / "bad.yaml"
    bad.write_text("image_width: 96\nimage_height: 64\ncamera_matrix: {rows: 3, cols: 3, data: [1, 2]}\n")
    video = write_video(tmp_path / "v.mp4", 2, FPS)
    broken = ServiceProcess("camera", router_endpoint, ["--set", f"source={video}", "--set", f"calibration={bad}"])
    with broken:
        assert wait_until(lambda: not broken.alive(), 30)
    assert broken.proc is not None and broken.proc.returncode == 2
    assert "'camera_matrix'" in broken.output and "bad.yaml" in broken.output


def test_pace_perception_is_refused_for_a_live_camera():
    from riskfield.services.camera.node import CameraSettings

    with pytest.raises(ValueError, match="live camera"):
        CameraSettings(source="/dev/video0", pace="perception")
    with pytest.raises(ValueError, match="both width and height"):
        CameraSettings(source="x.mp4", width=640)
    assert CameraSettings(source=str(Path("x.mp4"))).encoding == "jpeg"


def test_a_jpeg_without_huffman_tables_is_re_encoded_for_perception(router_endpoint, tmp_path):
    """A UVC-style frame (no DHT) would not decode in Pillow, perception's decoder: it goes out
    re-encoded, complete, and counted."""
    robot = "t_cam_dht"
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / "uvc.jpg").write_bytes(strip_huffman_tables(pillow_jpeg(frame_pixels(5), quality=95)))
    with client_session(router_endpoint) as s:
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        status = StatusWatch(s, f"rf/{robot}/status/camera")
        with _camera(robot, router_endpoint, f"source={folder}") as cam:
            msg = images.wait(1, 20)[0]
            st = status.wait(lambda st: st.extra.get("eof") == 1 and st.extra.get("frames_published") == 1)
            assert cam.stop() == 0, cam.output
        images.close()
        status.close()
    assert msg.encoding == "jpeg" and read_index(pixels(msg)) == 5  # pixels() is Pillow
    assert st.extra["jpeg_reencoded"] == 1
