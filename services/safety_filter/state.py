"""The robot state as the filter sees it, and the SO(3) series the barrier models share (rotations
from quaternions and yaw come from ``riskfield.services.geometry.transforms``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from riskfield.protocol import RobotState

from ..geometry.transforms import quat_to_matrix, yaw_matrix


def skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _series(w: np.ndarray, t: float, c1: float, c2: float) -> np.ndarray:
    """t·I + c1·[w]× + c2·[w]×², written out (this runs several times per control step)."""
    x, y, z = float(w[0]), float(w[1]), float(w[2])
    xx, yy, zz, xy, xz, yz = x * x, y * y, z * z, x * y, x * z, y * z
    return np.array([
        [t - c2 * (yy + zz), -c1 * z + c2 * xy, c1 * y + c2 * xz],
        [c1 * z + c2 * xy, t - c2 * (xx + zz), -c1 * x + c2 * yz],
        [-c1 * y + c2 * xz, c1 * x + c2 * yz, t - c2 * (xx + yy)],
    ])


def so3_exp(w: np.ndarray) -> np.ndarray:
    """exp([w]×): the rotation by angle |w| about w (Rodrigues)."""
    th = math.sqrt(float(w[0]) ** 2 + float(w[1]) ** 2 + float(w[2]) ** 2)
    if th < 1e-9:
        return _series(w, 1.0, 1.0, 0.5)
    return _series(w, 1.0, math.sin(th) / th, (1 - math.cos(th)) / th**2)


def so3_integral(w: np.ndarray, t: float) -> np.ndarray:
    """∫₀ᵗ exp(s [w]×) ds: maps a constant body-frame velocity to the displacement over t
    while the body turns at the constant body rate w."""
    th = math.sqrt(float(w[0]) ** 2 + float(w[1]) ** 2 + float(w[2]) ** 2)
    if abs(th * t) < 1e-6:
        return _series(w, t, 0.5 * t * t, t**3 / 6.0)
    return _series(w, t, (1 - math.cos(th * t)) / th**2, (th * t - math.sin(th * t)) / th**3)


@dataclass(frozen=True)
class FilterState:
    """Position (world), orientation (body → world rotation), world-frame velocities."""

    position: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def yaw(self) -> float:
        return math.atan2(self.rotation[1, 0], self.rotation[0, 0])

    @classmethod
    def from_message(cls, msg: RobotState) -> FilterState:
        return cls(np.array(msg.position, np.float64), quat_to_matrix(msg.orientation),
                   np.array(msg.linear_velocity, np.float64), np.array(msg.angular_velocity, np.float64))

    @classmethod
    def planar(cls, x: float, y: float, yaw: float, z: float = 0.0,
               velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> FilterState:
        return cls(np.array([x, y, z], np.float64), yaw_matrix(yaw), np.array(velocity, np.float64))

    def is_finite(self) -> bool:
        return bool(np.isfinite(self.position).all() and np.isfinite(self.rotation).all()
                    and np.isfinite(self.velocity).all() and np.isfinite(self.angular_velocity).all())
