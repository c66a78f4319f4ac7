"""Undistortion: the remap agrees with the lens model it inverts, on points and on whole images."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.camera.calibration import Calibration
from riskfield.services.camera.undistort import Undistorter, distort_normalised, source_pixels

W, H = 160, 120
K = np.array([[120.0, 0.0, 79.5], [0.0, 118.0, 59.5], [0.0, 0.0, 1.0]])


def undistort_normalised(xd: np.ndarray, yd: np.ndarray, D: np.ndarray, model: str) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of the lens model by fixed-point iteration (what cv::undistortPoints does)."""
    x, y = xd.copy(), yd.copy()
    for _ in range(60):
        fx, fy = distort_normalised(x, y, D, model)
        x, y = x + (xd - fx), y + (yd - fy)
    return x, y


lenses = st.one_of(
    st.tuples(st.just("plumb_bob"), st.tuples(st.floats(-0.3, 0.1), st.floats(-0.05, 0.05),
                                              st.floats(-0.002, 0.002), st.floats(-0.002, 0.002),
                                              st.floats(-0.01, 0.01))),
    st.tuples(st.just("equidistant"), st.tuples(st.floats(-0.05, 0.05), st.floats(-0.01, 0.01),
                                                st.floats(-0.002, 0.002), st.floats(-0.001, 0.001))),
)


def test_no_distortion_is_the_identity():
    rgb = np.random.default_rng(1).integers(0, 256, (H, W, 3), dtype=np.uint8)
    u = Undistorter(Calibration(W, H, K, np.zeros(5)))
    np.testing.assert_array_equal(u(rgb), rgb)
    assert u.coverage == 1.0


@settings(max_examples=50)
@given(lenses, st.floats(0.7, 1.0), st.integers(0, 2**32 - 1))
def test_each_output_pixel_reads_the_raw_pixel_its_ray_lands_on(lens, zoom, seed):
    model, coeffs = lens
    D = np.array(coeffs)
    P = K.copy()
    P[0, 0] *= zoom
    P[1, 1] *= zoom
    calib = Calibration(W, H, K, D, model, P=P)
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, W - 1, 200), rng.uniform(0, H - 1, 200)
    # Within the radius where the lens model is one-to-one (a strong barrel folds back beyond it).
    keep = np.hypot((u - P[0, 2]) / P[0, 0], (v - P[1, 2]) / P[1, 1]) < 0.6
    u, v = u[keep], v[keep]
    su, sv = source_pixels(calib, u, v)
    # Back from the raw pixel: undistort its normalised point, project with P: the output pixel.
    xd, yd = (su - K[0, 2]) / K[0, 0], (sv - K[1, 2]) / K[1, 1]
    x, y = undistort_normalised(xd, yd, D, model)
    np.testing.assert_allclose(P[0, 0] * x + P[0, 2], u, atol=1e-6)
    np.testing.assert_allclose(P[1, 1] * y + P[1, 2], v, atol=1e-6)


def test_rectification_rotates_the_rays():
    angle = np.deg2rad(5.0)
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    calib = Calibration(W, H, K, np.zeros(5), R=R)
    u, v = np.array([10.0, 80.0, 150.0]), np.array([5.0, 60.0, 110.0])
    su, sv = source_pixels(calib, u, v)
    ray = R.T @ np.linalg.inv(K) @ np.stack([u, v, np.ones(3)])
    q = K @ (ray / ray[2])
    np.testing.assert_allclose(su, q[0], atol=1e-9)
    np.testing.assert_allclose(sv, q[1], atol=1e-9)


def _pattern(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A smooth image of the undistorted scene (bilinear sampling is nearly exact on it)."""
    return 127.5 + 100 * np.sin(u / 9.0) * np.cos(v / 7.0)


def test_a_distorted_image_comes_out_as_the_pinhole_image():
    D = np.array([-0.25, 0.06, 0.001, -0.0015, 0.0])
    calib = Calibration(W, H, K, D)
    # The raw image a lens would make of the pattern: each raw pixel shows the scene point that
    # its undistorted ray sees.
    v, u = np.mgrid[0:H, 0:W].astype(float)
    x, y = undistort_normalised((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], D, "plumb_bob")
    raw_value = _pattern(K[0, 0] * x + K[0, 2], K[1, 1] * y + K[1, 2])
    raw = np.repeat(np.clip(np.rint(raw_value), 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    out = Undistorter(calib)(raw).astype(float)[..., 0]
    expected = _pattern(u, v)
    seen = out > 0  # the corners the lens does not see are black
    core = seen.copy()
    core[:8], core[-8:], core[:, :8], core[:, -8:] = False, False, False, False
    assert np.abs(out[core] - expected[core]).mean() < 1.5
    assert np.abs(out[core] - expected[core]).max() < 8
    # Compared with leaving the distortion in, undistortion is what makes it match.
    assert np.abs(raw[..., 0].astype(float)[core] - expected[core]).mean() > 10


def test_wrong_size_is_refused():
    u = Undistorter(Calibration(W, H, K, np.array([0.1, 0, 0, 0])))
    try:
        u(np.zeros((H // 2, W // 2, 3), np.uint8))
    except ValueError as exc:
        assert "calibration" in str(exc)
    else:
        raise AssertionError("a frame of another size was undistorted")
