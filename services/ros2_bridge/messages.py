"""``geometry_msgs/Twist`` and ``nav_msgs/Odometry`` ⇄ riskfield messages.

Frames (REP 103/105): body frame = ``base_link`` (x forward, y left, z up), the same as the
body frame of ``VelocityCommand``; the map frame = the odometry frame (ENU). An Odometry's
twist is expressed in its child frame (the body), so it is rotated into the world frame for
``RobotState``, whose velocities are world-frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import Header, RobotState, VelocityCommand

from .cdr import CdrReader, CdrWriter


def encode_twist(cmd: VelocityCommand) -> bytes:
    w = CdrWriter()
    w.float64(*cmd.linear, *cmd.angular)
    return w.bytes()


def decode_twist(data: bytes) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    r = CdrReader(data)
    v = r.float64(6)
    return (v[0], v[1], v[2]), (v[3], v[4], v[5])


@dataclass(frozen=True)
class Odometry:
    sec: int
    nanosec: int
    frame_id: str
    child_frame_id: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]  # x, y, z, w
    pose_covariance: tuple[float, ...]
    linear: tuple[float, float, float]  # child (body) frame
    angular: tuple[float, float, float]
    twist_covariance: tuple[float, ...]


def encode_odometry(o: Odometry) -> bytes:
    w = CdrWriter()
    w.int32(o.sec)
    w.uint32(o.nanosec)
    w.string(o.frame_id)
    w.string(o.child_frame_id)
    w.float64(*o.position, *o.orientation)
    w.float64(*o.pose_covariance)
    w.float64(*o.linear, *o.angular)
    w.float64(*o.twist_covariance)
    return w.bytes()


def decode_odometry(data: bytes) -> Odometry:
    r = CdrReader(data)
    sec, nanosec = r.int32(), r.uint32()
    frame_id, child = r.string(), r.string()
    pose = r.float64(7)
    pcov = r.float64(36)
    twist = r.float64(6)
    tcov = r.float64(36)
    return Odometry(sec, nanosec, frame_id, child, pose[:3], pose[3:], pcov, twist[:3], twist[3:], tcov)


def _rotate(q: tuple[float, float, float, float], v: tuple[float, float, float]) -> np.ndarray:
    x, y, z, w = q
    u = np.array([x, y, z])
    v = np.asarray(v, dtype=float)
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def odometry_to_state(o: Odometry) -> RobotState:
    """World-frame RobotState from an Odometry (twist rotated out of the body frame)."""
    q = np.asarray(o.orientation, dtype=float)
    n = float(np.linalg.norm(q))
    if not math.isfinite(n) or n < 1e-6:
        raise ValueError("odometry orientation is not a quaternion")
    qn = tuple(float(c) for c in q / n)
    stamp = max(0, o.sec) * 1_000_000_000 + o.nanosec
    return RobotState(
        header=Header(stamp_ns=stamp, frame_id=o.frame_id or "map"),
        position=o.position,
        orientation=qn,
        linear_velocity=tuple(_rotate(qn, o.linear)),
        angular_velocity=tuple(_rotate(qn, o.angular)),
    )
