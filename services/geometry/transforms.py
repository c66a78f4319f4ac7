"""Rotations and rigid transforms: the one set of helpers every service uses.

Conventions: quaternions are ``(x, y, z, w)`` (scipy's and ROS's order, and ``RobotState``'s),
rotation matrices map body (or camera) coordinates to world, ``T_AB`` is the 4×4 transform taking
points in frame B to frame A, yaw is the heading about world +z. The general conversions are
scipy's ``Rotation`` (``scipy/spatial/transform/_rotation.pyx``: ``from_quat`` normalises,
``from_euler`` with upper-case axes is intrinsic); the helpers below that run per control step
or per pixel are closed forms, checked against ``Rotation`` by ``tests/geometry``. scipy is
imported by the functions that use it, not by the module: the bridges and the ROS 2 bridge use
the closed forms without scipy installed.

``riskfield.protocol.RobotState.yaw`` keeps its own two-line closed form because the wire
contract depends on numpy, pydantic and msgpack only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

Quaternion = tuple[float, float, float, float]


def quat_to_matrix(q: Sequence[float] | np.ndarray) -> np.ndarray:
    """Rotation matrix (body → world) of a quaternion xyzw (normalised here).

    A non-finite or zero quaternion gives a NaN matrix instead of scipy's ValueError, so callers
    that check finiteness (the filter brakes on an invalid state) keep doing so.
    """
    q = np.asarray(q, np.float64)
    if not (np.isfinite(q).all() and q.any()):
        return np.full((3, 3), np.nan)
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(q).as_matrix()


def matrix_to_quat(R: np.ndarray) -> Quaternion:
    """Unit quaternion (x, y, z, w) with w ≥ 0 of a rotation matrix."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(R, np.float64)).as_quat()
    if q[3] < 0:
        q = -q
    return float(q[0]), float(q[1]), float(q[2]), float(q[3])


def euler_zyx_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) · Ry(pitch) · Rx(roll): intrinsic Z-Y-X (aerospace) Euler angles."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()


def quat_rotate(q: Sequence[float] | np.ndarray, v: Sequence[float] | np.ndarray) -> np.ndarray:
    """``R(q)·v`` for a unit quaternion ``q = (x, y, z, w)``, closed form: ``v + 2u×(u×v + w v)``
    with ``u = (x, y, z)``."""
    u, w = np.asarray(q[:3], np.float64), float(q[3])
    v = np.asarray(v, np.float64)
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def quat_mul(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` in (x, y, z, w) order: the rotation ``b`` then ``a``."""
    ax, ay, az, aw = (float(c) for c in a)
    bx, by, bz, bw = (float(c) for c in b)
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def wrap_angle(a: float) -> float:
    """The angle in [−π, π) equal to ``a`` modulo 2π: the one wrap every heading error and
    integrated yaw uses."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def yaw_quaternion(yaw: float) -> np.ndarray:
    """Quaternion xyzw of a rotation by ``yaw`` about +z (closed form: the simulator's per-step pose)."""
    return np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])


def yaw_of(q: Sequence[float] | np.ndarray) -> float:
    """Heading about +z of a unit quaternion xyzw: the angle of the body x axis projected on the
    floor, ``atan2(R₁₀, R₀₀)`` (closed form; equals ``Rotation.as_euler("ZYX")[0]``)."""
    x, y, z, w = (float(c) for c in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def yaw_matrix(yaw: float) -> np.ndarray:
    """3×3 rotation about +z (closed form: built on every control step of the filter's roll-outs)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose_matrix(x: float, y: float, z: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """4×4 transform of a floor placement: translation and a rotation about +z."""
    T = np.eye(4)
    T[:3, :3] = yaw_matrix(yaw)
    T[:3, 3] = (x, y, z)
    return T


def world_to_body(q: Sequence[float] | np.ndarray, v: np.ndarray) -> np.ndarray:
    """A world-frame vector in the body frame of orientation ``q`` (xyzw): Rᵀ v."""
    return quat_to_matrix(q).T @ np.asarray(v, dtype=np.float64)


def look_at(eye: np.ndarray, target: np.ndarray, up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """T_WC of a camera at ``eye`` looking at ``target`` (OpenCV axes: z forward, y down)."""
    eye, target = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def orbit(target: Sequence[float] | np.ndarray, n: int = 5, radius: float = 0.2, height: float = 0.3,
          spread: float = 0.6) -> list[np.ndarray]:
    """``n`` camera poses T_WC on an arc of ``radius`` around the origin at ``height``, looking at ``target``."""
    out = []
    for a in np.linspace(-spread, spread, n):
        eye = np.array([-radius * np.cos(a), radius * np.sin(a), height])
        out.append(look_at(eye, np.asarray(target, dtype=np.float64)))
    return out


def transform_points(T: np.ndarray, P: np.ndarray, dtype: type = np.float64) -> np.ndarray:
    """``R·p + t`` for every row p of ``P`` (..., 3), with ``T`` a 4x4 (or 3x4) transform.

    Not ``P @ R.T``: that calls a multi-threaded BLAS gemm whose threads spin-wait; on a small
    machine shared with other processes a 1 ms product can take 50–100 ms. Three fused
    multiply-adds per output column are as fast unloaded and never stall.
    """
    P = np.asarray(P)
    R, t = np.asarray(T, np.float64)[:3, :3], np.asarray(T, np.float64)[:3, 3]
    # In float64 whatever ``dtype`` (stored as it): numpy 2 promotes a float32 array times a
    # float64 scalar to float64, numpy 1 did not, and the compiled kernels compute in float64.
    x, y, z = P[..., 0].astype(np.float64), P[..., 1].astype(np.float64), P[..., 2].astype(np.float64)
    out = np.empty((*P.shape[:-1], 3), dtype)
    for i in range(3):
        out[..., i] = R[i, 0] * x + R[i, 1] * y + R[i, 2] * z + t[i]
    return out


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out
