"""ROS 2 cameras into `camera/image` through the ROS 2 bridge: sensor_msgs/Image, CompressedImage
and CameraInfo, built with pycdr2 from the official .msg files (an encoder independent of rosbags,
which the bridge decodes with). No ``from __future__ import annotations``: pycdr2 reads the
field types at class creation."""

import io
import time
from dataclasses import dataclass

import numpy as np
import pytest
from camera.media import pillow_jpeg, strip_huffman_tables
from PIL import Image as PILImage
from pycdr2 import IdlStruct  # the dev extra's: a broken install fails here rather than skipping
from pycdr2.types import array, float64, sequence, uint8, uint32
from tools import ros_idl as idl

from riskfield.protocol import Image
from riskfield.services.ros2_bridge.messages import (
    RosCodec,
    decode_camera_info,
    decode_compressed_image,
    decode_image,
    image_stamp,
)
from riskfield.testing import Collector, ServiceProcess, StatusWatch, client_session, wait_alive, wait_until

Hdr, Time = idl.Hdr, idl.Time


# sensor_msgs/msg/Image.msg, CompressedImage.msg, RegionOfInterest.msg, CameraInfo.msg (ROS 2 Jazzy)
@dataclass
class RosImage(IdlStruct, typename="sensor_msgs/msg/Image"):
    header: Hdr
    height: uint32
    width: uint32
    encoding: str
    is_bigendian: uint8
    step: uint32
    data: sequence[uint8]


@dataclass
class RosCompressedImage(IdlStruct, typename="sensor_msgs/msg/CompressedImage"):
    header: Hdr
    format: str
    data: sequence[uint8]


@dataclass
class Roi(IdlStruct, typename="sensor_msgs/msg/RegionOfInterest"):
    x_offset: uint32
    y_offset: uint32
    height: uint32
    width: uint32
    do_rectify: bool


@dataclass
class RosCameraInfo(IdlStruct, typename="sensor_msgs/msg/CameraInfo"):
    header: Hdr
    height: uint32
    width: uint32
    distortion_model: str
    d: sequence[float64]
    k: array[float64, 9]
    r: array[float64, 9]
    p: array[float64, 12]
    binning_x: uint32
    binning_y: uint32
    roi: Roi


NOW = 1_800_000_000 * 10**9
K = [300.0, 0.0, 31.5, 0.0, 301.0, 23.5, 0.0, 0.0, 1.0]
P = [280.0, 0.0, 32.0, 0.0, 0.0, 282.0, 24.0, 0.0, 0.0, 0.0, 1.0, 0.0]
I3 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]


def _hdr(ns: int, frame: str = "camera_optical_frame") -> object:
    return Hdr(Time(ns // 10**9, ns % 10**9), frame)


def ros_image(rgb: np.ndarray, encoding: str, ns: int = NOW, pad: int = 0) -> bytes:
    h, w = rgb.shape[:2]
    if encoding == "bgr8":
        px = rgb[:, :, ::-1]
    elif encoding == "rgba8":
        px = np.concatenate([rgb, np.full((h, w, 1), 255, np.uint8)], axis=2)
    elif encoding == "bgra8":
        px = np.concatenate([rgb[:, :, ::-1], np.full((h, w, 1), 7, np.uint8)], axis=2)
    elif encoding == "mono8":
        px = rgb[:, :, :1]
    else:
        px = rgb
    rows = px.reshape(h, -1)
    rows = np.concatenate([rows, np.zeros((h, pad), np.uint8)], axis=1)  # step > width · channels
    return RosImage(_hdr(ns), h, w, encoding, 0, rows.shape[1], rows.reshape(-1).tolist()).serialize()


def ros_info(d: list[float], w: int = 64, h: int = 48) -> bytes:
    return RosCameraInfo(_hdr(NOW), h, w, "plumb_bob", d, K, I3, P, 0, 0, Roi(0, 0, 0, 0, False)).serialize()


def _rgb(h: int = 48, w: int = 64) -> np.ndarray:
    return np.random.default_rng(3).integers(0, 256, (h, w, 3), dtype=np.uint8)


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "rgba8", "bgra8", "mono8"])
@pytest.mark.parametrize("pad", [0, 5])
def test_images_become_rgb8(encoding, pad):
    rgb = _rgb()
    image, from_ros = decode_image(RosCodec("jazzy"), ros_image(rgb, encoding, pad=pad), NOW + 30_000_000)
    expected = np.repeat(rgb[:, :, :1], 3, axis=2) if encoding == "mono8" else rgb
    np.testing.assert_array_equal(image.data, expected)
    assert (image.encoding, image.width, image.height) == ("rgb8", 64, 48)
    assert from_ros and image.header.stamp_ns == NOW and image.header.frame_id == "camera_optical_frame"


def test_bad_images_are_refused():
    codec = RosCodec("humble")
    depth = RosImage(_hdr(NOW), 2, 2, "16UC1", 0, 4, [0] * 8).serialize()
    with pytest.raises(ValueError, match="not supported"):
        decode_image(codec, depth, NOW)
    short = RosImage(_hdr(NOW), 48, 64, "rgb8", 0, 192, [0] * 100).serialize()
    with pytest.raises(ValueError, match="does not fit"):
        decode_image(codec, short, NOW)
    with pytest.raises(ValueError, match="CDR"):
        decode_image(codec, b"\x00\x01\x00\x00garbage", NOW)


def test_simulation_time_stamps_give_way_to_the_arrival():
    assert image_stamp(100 * 10**9, NOW) == (NOW, False)  # use_sim_time: 100 s after the simulation started
    assert image_stamp(NOW - 2 * 10**9, NOW) == (NOW - 2 * 10**9, True)
    assert image_stamp(NOW + 5 * 10**9, NOW) == (NOW, False)


def test_compressed_jpeg_goes_through_untouched():
    codec = RosCodec("jazzy")
    jpeg = pillow_jpeg(_rgb(), quality=90)
    msg = RosCompressedImage(_hdr(NOW), "bgr8; jpeg compressed bgr8", list(jpeg)).serialize()
    image, _ = decode_compressed_image(codec, msg, NOW)
    assert image.encoding == "jpeg" and image.data == jpeg and (image.width, image.height) == (64, 48)
    png = io.BytesIO()
    PILImage.fromarray(_rgb()).save(png, format="PNG")
    with pytest.raises(ValueError, match="only jpeg"):
        decode_compressed_image(codec, RosCompressedImage(_hdr(NOW), "png", list(png.getvalue())).serialize(), NOW)
    bare = RosCompressedImage(_hdr(NOW), "jpeg", list(strip_huffman_tables(jpeg))).serialize()
    with pytest.raises(ValueError, match="Huffman"):
        decode_compressed_image(codec, bare, NOW)


def test_camera_info_intrinsics():
    codec = RosCodec("jazzy")
    distorted = decode_camera_info(codec, ros_info([-0.2, 0.05, 0.0, 0.0, 0.0]))
    assert distorted.intrinsics(rectified=True) == (280.0, 282.0, 32.0, 24.0)  # P: the rectified image
    assert distorted.intrinsics(rectified=False) is None  # raw and distorted: no pinhole model
    clean = decode_camera_info(codec, ros_info([0.0] * 5))
    assert clean.intrinsics(rectified=False) == (300.0, 301.0, 31.5, 23.5)
    uncalibrated = RosCameraInfo(_hdr(NOW), 48, 64, "", [], [0.0] * 9, [0.0] * 9, [0.0] * 12, 0, 0,
                                 Roi(0, 0, 0, 0, False)).serialize()
    assert decode_camera_info(codec, uncalibrated).intrinsics(rectified=True) is None


def test_bridge_node_republishes_ros_images_with_intrinsics(router_endpoint):
    robot, ns = "t_ros_cam", "t_cam_ns"
    args = ["--robot", robot, "--set", f"namespace={ns}", "--set", "image_topic=camera/image_rect",
            "--set", "compressed_image_topic=camera/image_raw/compressed",
            "--set", "camera_info_topic=camera/camera_info", "--set", "camera_info_rectified=true",
            "--set", "status_period_s=0.1"]
    rgb = _rgb()
    with ServiceProcess("ros2-bridge", router_endpoint, args) as bridge, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/ros2-bridge"), bridge.output
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        status = StatusWatch(s, f"rf/{robot}/status/ros2-bridge")
        # Before any camera_info: the image goes out uncalibrated.
        stamp = time.time_ns() - 20_000_000
        s.put(f"{ns}/camera/image_rect", ros_image(rgb, "bgr8", stamp), encoding="application/cdr")
        first = images.wait(1)[0]
        assert first.intrinsics is None and first.header.stamp_ns == stamp
        np.testing.assert_array_equal(first.data, rgb)
        s.put(f"{ns}/camera/camera_info", ros_info([-0.2, 0.05, 0.0, 0.0, 0.0]), encoding="application/cdr")
        status.wait(lambda st: st.received.get(f"{ns}/camera/camera_info", 0) >= 1)
        s.put(f"{ns}/camera/image_rect", ros_image(rgb, "rgb8", stamp + 1), encoding="application/cdr")
        jpeg = pillow_jpeg(rgb)
        s.put(f"{ns}/camera/image_raw/compressed",
              RosCompressedImage(_hdr(100 * 10**9), "jpeg", list(jpeg)).serialize(), encoding="application/cdr")
        msgs = images.wait(3)
        raw_msg = next(m for m in msgs[1:] if m.encoding == "rgb8")
        jpeg_msg = next(m for m in msgs[1:] if m.encoding == "jpeg")
        assert raw_msg.intrinsics == (280.0, 282.0, 32.0, 24.0) and raw_msg.header.stamp_ns == stamp + 1
        assert jpeg_msg.data == jpeg and jpeg_msg.intrinsics == (280.0, 282.0, 32.0, 24.0)
        assert abs(jpeg_msg.header.stamp_ns - time.time_ns()) < 60 * 10**9  # simulation time → arrival
        # Garbage on an image key: counted, and the bridge keeps serving.
        s.put(f"{ns}/camera/image_rect", b"\x00\x01\x00\x00junk", encoding="application/cdr")
        st = status.wait(lambda st: st.extra.get("image_invalid", 0) >= 1)
        assert st.extra.get("image_stamp_fallbacks") == 1
        s.put(f"{ns}/camera/image_rect", ros_image(rgb, "mono8", stamp + 2), encoding="application/cdr")
        assert wait_until(lambda: any(m.header.stamp_ns == stamp + 2 for m in images.items))
        assert bridge.stop() == 0, bridge.output
        images.close()
        status.close()
