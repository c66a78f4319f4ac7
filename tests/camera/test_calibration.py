"""Calibration files: ROS camera_info YAML and OpenCV FileStorage YAML, parsed exactly; bad files
refused with the key named."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from riskfield.services.camera.calibration import Calibration, CalibrationError, load_calibration, parse_calibration

# What cv::FileStorage writes (OpenCV's calibration sample, samples/cpp/calibration.cpp): the
# %YAML:1.0 header, !!opencv-matrix tags, numbers in %.16e with data wrapped over lines.
OPENCV_SAMPLE = """\
%YAML:1.0
---
calibration_time: "Fri 04 Dec 2026 10:00:00 UTC"
image_width: 640
image_height: 480
board_width: 9
board_height: 6
square_size: 2.5000000000000000e-02
flags: 0
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 5.3219183612059011e+02, 0., 3.1913867640549431e+02, 0.,
       5.3210419787734283e+02, 2.4290498838224548e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -2.8133713413466113e-01, 8.1395393306016302e-02,
       1.2138117893813651e-03, -1.5765604290553929e-04,
       -1.2083455706880000e-02 ]
avg_reprojection_error: 2.3514999999999999e-01
"""

ROS_SAMPLE = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [532.19, 0, 319.14, 0, 532.10, 242.90, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.2813, 0.0814, 0.0012, -0.0002, -0.0121]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [470.5, 0, 321.0, 0, 0, 495.2, 240.3, 0, 0, 0, 1, 0]
"""


def test_opencv_filestorage_sample():
    c = parse_calibration(OPENCV_SAMPLE)
    assert (c.width, c.height, c.model) == (640, 480, "plumb_bob")
    assert c.K[0, 0] == 5.3219183612059011e02 and c.K[1, 2] == 2.4290498838224548e02
    assert c.D.tolist() == [-2.8133713413466113e-01, 8.1395393306016302e-02, 1.2138117893813651e-03,
                            -1.5765604290553929e-04, -1.2083455706880000e-02]
    assert c.intrinsics == c.raw_intrinsics  # no P in an OpenCV file: the pinhole image keeps K
    assert c.distorted


def test_ros_camera_info_sample(tmp_path):
    path = tmp_path / "head_camera.yaml"
    path.write_text(ROS_SAMPLE)
    c = load_calibration(path)
    assert c.name == "narrow_stereo" and c.model == "plumb_bob"
    assert c.raw_intrinsics == (532.19, 532.10, 319.14, 242.90)
    assert c.intrinsics == (470.5, 495.2, 321.0, 240.3)  # the rectified image's P
    assert c.D.size == 5 and c.distorted


def _ros_text(w: int, h: int, K: np.ndarray, D: np.ndarray, model: str, P: np.ndarray) -> str:
    def mat(rows: int, cols: int, a: np.ndarray) -> str:
        return f"\n  rows: {rows}\n  cols: {cols}\n  data: [{', '.join(repr(float(x)) for x in a.reshape(-1))}]"

    return (f"image_width: {w}\nimage_height: {h}\ncamera_name: cam\ncamera_matrix:{mat(3, 3, K)}\n"
            f"distortion_model: {model}\ndistortion_coefficients:{mat(1, D.size, D)}\n"
            f"rectification_matrix:{mat(3, 3, np.eye(3))}\nprojection_matrix:{mat(3, 4, P)}\n")


def _opencv_text(w: int, h: int, K: np.ndarray, D: np.ndarray) -> str:
    def mat(rows: int, cols: int, a: np.ndarray) -> str:
        nums = [f"{float(x):.16e}" for x in a.reshape(-1)]
        lines = ",\n       ".join(", ".join(nums[i:i + 3]) for i in range(0, len(nums), 3))
        return f" !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {lines} ]"

    return (f"%YAML:1.0\n---\nimage_width: {w}\nimage_height: {h}\ncamera_matrix:{mat(3, 3, K)}\n"
            f"distortion_coefficients:{mat(D.size, 1, D)}\n")


finite = st.floats(-0.5, 0.5, allow_nan=False, allow_infinity=False)


@st.composite
def cameras(draw: st.DrawFn) -> tuple[int, int, np.ndarray, np.ndarray, str]:
    w, h = draw(st.integers(16, 4096)), draw(st.integers(16, 4096))
    fx, fy = draw(st.floats(20, 5000)), draw(st.floats(20, 5000))
    cx, cy = draw(st.floats(0, w)), draw(st.floats(0, h))
    skew = draw(st.sampled_from([0.0, draw(st.floats(-2, 2))]))
    model = draw(st.sampled_from(["plumb_bob", "rational_polynomial", "equidistant"]))
    n = {"plumb_bob": draw(st.sampled_from([4, 5])), "rational_polynomial": 8, "equidistant": 4}[model]
    D = np.array(draw(st.lists(finite, min_size=n, max_size=n)))
    K = np.array([[fx, skew, cx], [0, fy, cy], [0, 0, 1.0]])
    return w, h, K, D, model


@given(cameras(), st.floats(0.5, 1.5))
def test_ros_files_parse_exactly(cam, p_scale):
    w, h, K, D, model = cam
    P = np.hstack([K * np.array([[p_scale], [p_scale], [1]]), np.zeros((3, 1))])
    c = parse_calibration(_ros_text(w, h, K, D, model, P))
    assert (c.width, c.height, c.model) == (w, h, model)
    np.testing.assert_array_equal(c.K, K)
    np.testing.assert_array_equal(c.D, D)
    np.testing.assert_array_equal(c.P, P[:, :3])


@given(cameras())
def test_opencv_files_parse_exactly(cam):
    w, h, K, D, model = cam
    if model == "equidistant":  # OpenCV's pinhole file has no model key: its vector is read as pinhole
        D = np.concatenate([D, [0.0]])
    c = parse_calibration(_opencv_text(w, h, K, D))
    assert (c.width, c.height) == (w, h) and c.model == "plumb_bob"
    np.testing.assert_array_equal(c.K, K)
    np.testing.assert_array_equal(c.D, D)
    np.testing.assert_array_equal(c.P, K)


def test_opencv_fisheye_and_long_vectors():
    K = np.array([[400.0, 0, 320], [0, 400, 240], [0, 0, 1]])
    fisheye = _opencv_text(640, 480, K, np.array([0.1, -0.01, 0.002, -0.0003])) + "distortion_model: fisheye\n"
    assert parse_calibration(fisheye).model == "equidistant"
    zeros_tail = np.concatenate([[0.1, -0.01, 0.0, 0.0, 0.001, 0.0, 0.0, 0.0], np.zeros(6)])
    assert parse_calibration(_opencv_text(640, 480, K, zeros_tail)).D.size == 8
    prism = zeros_tail.copy()
    prism[9] = 0.01
    with pytest.raises(CalibrationError, match="thin-prism"):
        parse_calibration(_opencv_text(640, 480, K, prism))


@pytest.mark.parametrize(("text", "words"), [
    ("image_width: 640\nimage_height: 480\n", "camera matrix"),
    (ROS_SAMPLE.replace("image_width: 640\n", ""), "image width"),
    (ROS_SAMPLE.replace("image_height: 480", "image_height: -4"), "'image_height'"),
    (ROS_SAMPLE.replace("data: [532.19, 0, 319.14,", "data: [532.19, 319.14,"), "'camera_matrix'"),
    (ROS_SAMPLE.replace("532.19, 0, 319.14", ".nan, 0, 319.14"), "NaN"),
    (ROS_SAMPLE.replace("plumb_bob", "omnidirectional"), "not supported"),
    (ROS_SAMPLE.replace("470.5, 0, 321.0, 0,", "470.5, 0, 321.0, -35.2,"), "baseline"),
    (ROS_SAMPLE.replace("  cols: 5\n  data: [-0.2813, 0.0814, 0.0012, -0.0002, -0.0121]",
                        "  cols: 3\n  data: [-0.2813, 0.0814, 0.0012]"), "coefficients"),
    (ROS_SAMPLE.replace("data: [1, 0, 0, 0, 1, 0, 0, 0, 1]", "data: [2, 0, 0, 0, 1, 0, 0, 0, 1]"), "rotation"),
    (ROS_SAMPLE.replace("data: [532.19, 0, 319.14, 0, 532.10, 242.90, 0, 0, 1]",
                        "data: [-532.19, 0, 319.14, 0, 532.10, 242.90, 0, 0, 1]"), "fx, fy > 0"),
    ("- just\n- a list\n", "top level"),
    ("camera_matrix: [unclosed\n", "not YAML"),
])
def test_bad_files_are_refused_naming_what_is_wrong(text, words):
    with pytest.raises(CalibrationError, match=words) as err:
        parse_calibration(text, "cam.yaml")
    assert str(err.value).startswith("cam.yaml: ")


def test_missing_file_is_a_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_calibration(tmp_path / "nope.yaml")


def test_scaled_to_another_mode_of_the_same_aspect():
    c = parse_calibration(ROS_SAMPLE)
    half = c.scaled(320, 240)
    assert half.K[0, 0] == pytest.approx(532.19 / 2) and half.K[1, 1] == pytest.approx(532.10 / 2)
    # Pixel centres at integers: the centre of the image stays the centre.
    assert half.K[0, 2] == pytest.approx((319.14 + 0.5) / 2 - 0.5)
    assert half.intrinsics[0] == pytest.approx(470.5 / 2)
    np.testing.assert_array_equal(half.D, c.D)
    assert c.scaled(640, 480) is c
    with pytest.raises(CalibrationError, match="aspect ratio"):
        c.scaled(640, 360)


def test_an_undistorted_calibration_is_not_distorted():
    K = np.array([[100.0, 0, 50], [0, 100, 40], [0, 0, 1]])
    assert not Calibration(100, 80, K, np.zeros(5)).distorted
    assert Calibration(100, 80, K, np.array([0.1, 0, 0, 0])).distorted
