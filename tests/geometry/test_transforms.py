"""The transform helpers against scipy's Rotation (the closed forms) and against each other."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from riskfield.protocol import RobotState
from riskfield.services.geometry.transforms import (
    euler_zyx_matrix,
    inverse,
    look_at,
    matrix_to_quat,
    orbit,
    pose_matrix,
    quat_mul,
    quat_rotate,
    quat_to_matrix,
    transform_points,
    world_to_body,
    wrap_angle,
    yaw_matrix,
    yaw_of,
    yaw_quaternion,
)

angle = st.floats(-math.pi, math.pi)
quats = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1)
vec = st.lists(st.floats(-10, 10), min_size=3, max_size=3)


def same_angle(a: float, b: float, tol: float = 1e-9) -> bool:
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi) < tol


@settings(max_examples=200, deadline=None)
@given(q=quats)
def test_quaternion_and_matrix_round_trip(q: list) -> None:
    R = quat_to_matrix(q)
    np.testing.assert_allclose(R, Rotation.from_quat(q).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    back = matrix_to_quat(R)
    assert back[3] >= 0
    unit = np.asarray(q) / np.linalg.norm(q)
    assert abs(abs(np.dot(back, unit)) - 1.0) < 1e-9  # the same rotation (q and −q)


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0), (math.inf, 0.0, 0.0, 1.0)])
def test_a_degenerate_quaternion_gives_a_non_finite_matrix(q: tuple) -> None:
    assert not np.isfinite(quat_to_matrix(q)).any()


@settings(max_examples=200, deadline=None)
@given(yaw=angle)
def test_yaw_helpers_match_rotation_about_z(yaw: float) -> None:
    r = Rotation.from_euler("z", yaw)
    np.testing.assert_allclose(yaw_matrix(yaw), r.as_matrix(), atol=1e-12)
    q = yaw_quaternion(yaw)
    assert abs(abs(np.dot(q, r.as_quat())) - 1.0) < 1e-12
    assert same_angle(yaw_of(q), yaw, 1e-12)
    T = pose_matrix(1.0, -2.0, 0.5, yaw)
    np.testing.assert_allclose(T[:3, :3], r.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [1.0, -2.0, 0.5])


@settings(max_examples=200, deadline=None)
@given(q=quats)
def test_yaw_of_is_the_heading_of_the_body_x_axis_and_matches_the_wire_contract(q: list) -> None:
    unit = tuple(float(c) for c in np.asarray(q) / np.linalg.norm(q))
    R = Rotation.from_quat(unit).as_matrix()
    if math.hypot(R[0, 0], R[1, 0]) < 1e-6:
        return  # looking straight up or down: no heading
    assert same_angle(yaw_of(unit), math.atan2(R[1, 0], R[0, 0]))
    assert same_angle(yaw_of(unit), Rotation.from_quat(unit).as_euler("ZYX")[0])
    state = RobotState(position=(0, 0, 0), orientation=unit, linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0))
    assert state.yaw == pytest.approx(yaw_of(unit), abs=1e-12)  # protocol's own closed form agrees


@settings(max_examples=200, deadline=None)
@given(roll=angle, pitch=st.floats(-1.5, 1.5), yaw=angle)
def test_euler_zyx_is_yaw_then_pitch_then_roll(roll: float, pitch: float, yaw: float) -> None:
    def rot(axis: int, a: float) -> np.ndarray:
        return Rotation.from_rotvec(a * np.eye(3)[axis]).as_matrix()

    np.testing.assert_allclose(euler_zyx_matrix(roll, pitch, yaw), rot(2, yaw) @ rot(1, pitch) @ rot(0, roll),
                               atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(q=quats, t=vec, pts=st.lists(vec, min_size=1, max_size=20))
def test_transform_points_inverse_and_world_to_body(q: list, t: list, pts: list) -> None:
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(q)
    T[:3, 3] = t
    P = np.asarray(pts)
    out = transform_points(T, P)
    np.testing.assert_allclose(out, P @ T[:3, :3].T + T[:3, 3], atol=1e-9)
    np.testing.assert_allclose(transform_points(inverse(T), out), P, atol=1e-9)
    np.testing.assert_allclose(inverse(T) @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(world_to_body(q, T[:3, :3] @ P[0]), P[0], atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(eye=vec, target=vec)
def test_look_at_points_the_optical_axis_at_the_target_with_image_y_down(eye: list, target: list) -> None:
    e, g = np.asarray(eye), np.asarray(target)
    if np.linalg.norm(g - e) < 1e-3:
        return
    T = look_at(e, g)
    R = T[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R[:, 2], (g - e) / np.linalg.norm(g - e), atol=1e-9)
    assert R[2, 1] <= 1e-9  # image y (down) never points up


def test_orbit_looks_at_the_target_from_the_arc() -> None:
    poses = orbit([1.2, 0.0, 0.3], n=5, radius=0.2, height=0.3)
    assert len(poses) == 5
    for T in poses:
        assert np.hypot(T[0, 3], T[1, 3]) == pytest.approx(0.2) and T[2, 3] == pytest.approx(0.3)
        to_target = np.array([1.2, 0.0, 0.3]) - T[:3, 3]
        np.testing.assert_allclose(T[:3, 2], to_target / np.linalg.norm(to_target), atol=1e-12)


@settings(max_examples=300)
@given(a=st.floats(-1e4, 1e4))
def test_wrap_angle_is_the_same_angle_in_minus_pi_to_pi(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi <= w < math.pi
    assert math.cos(w) == pytest.approx(math.cos(a), abs=1e-9) and math.sin(w) == pytest.approx(math.sin(a), abs=1e-9)


def test_wrap_angle_at_the_seam() -> None:
    assert wrap_angle(math.pi) == -math.pi and wrap_angle(-math.pi) == -math.pi and wrap_angle(0.0) == 0.0


vectors = st.lists(st.floats(-10, 10), min_size=3, max_size=3)


@settings(max_examples=200)
@given(q=quats, r=quats, v=vectors)
def test_quaternion_rotate_and_product_are_scipys(q: list, r: list, v: list) -> None:
    q, r = np.asarray(q) / np.linalg.norm(q), np.asarray(r) / np.linalg.norm(r)
    np.testing.assert_allclose(quat_rotate(q, v), Rotation.from_quat(q).apply(v), atol=1e-9)
    product = Rotation.from_quat(quat_mul(q, r))
    np.testing.assert_allclose(product.as_matrix(), (Rotation.from_quat(q) * Rotation.from_quat(r)).as_matrix(),
                               atol=1e-9)


def test_the_transforms_load_without_scipy() -> None:
    """The bridges use the closed forms on a robot install: scipy comes in only with ``Rotation``."""
    import subprocess
    import sys

    code = "import sys, riskfield.services.geometry.transforms; print('scipy' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "False", r.stderr
