"""The one pinhole camera model: intrinsics, projection, unprojection and per-pixel rays.

Conventions (OpenCV): camera x right, y down, z forward; pixel (u, v) has its centre at integer
coordinates, so

    project:    (u, v) = (fx·x/z + cx, fy·y/z + cy)
    unproject:  p = depth · ((u − cx)/fx, (v − cy)/fy, 1)

and the ray of pixel (u, v) is ``((u − cx)/fx, (v − cy)/fy, 1)``. Casting that unnormalised
direction makes a hit distance equal to the **depth** z, and the pointmap is ``depth · ray``;
:meth:`PinholeCamera.unit_rays` gives the normalised directions for casts that want metric ranges.

The default image is 512×384 — what MASt3R-SLAM works at (a 640×480 frame resized and cropped).

Where the camera sits on the robot is the platform description's ``CameraMount``
(``protocol.platforms``; the LIMO's is ``LIMO.camera``); :func:`T_base_camera` turns one into the
optical frame's pose in ``base_link``, for the simulator's renders and perception's odometry alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskfield.protocol.platforms import CameraMount

from .transforms import euler_zyx_matrix

#: Base (x forward, y left, z up) ← optical (x right, y down, z forward), looking straight ahead.
R_BASE_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def T_base_camera(mount: CameraMount) -> np.ndarray:
    """4x4 optical → base_link: ``[R_z(yaw)·R_y(pitch)·R_x(roll)·R_BASE_OPTICAL | position]``.

    The angles turn the optical axis in base_link, so pitch > 0 (about base y, which points left)
    tilts it towards the floor."""
    T = np.eye(4)
    T[:3, :3] = euler_zyx_matrix(*(math.radians(a) for a in mount.rpy_deg)) @ R_BASE_OPTICAL
    T[:3, 3] = mount.position
    return T


@dataclass(frozen=True)
class PinholeCamera:
    width: int = 512
    height: int = 384
    fx: float = 256.0
    fy: float = 256.0
    cx: float = 255.5
    cy: float = 191.5

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0 or self.fx <= 0 or self.fy <= 0:
            raise ValueError("camera width, height, fx and fy must be positive")
        if not all(math.isfinite(v) for v in (self.fx, self.fy, self.cx, self.cy)):
            raise ValueError("camera intrinsics must be finite")

    @classmethod
    def from_fov(cls, width: int = 512, height: int = 384, hfov_deg: float = 90.0) -> PinholeCamera:
        """Square pixels, principal point at the image centre, horizontal field of view."""
        if not 1.0 < hfov_deg < 179.0:
            raise ValueError("hfov_deg must be between 1 and 179")
        f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
        return cls(width, height, f, f, (width - 1) / 2, (height - 1) / 2)

    @classmethod
    def centred(cls, width: int, height: int, fx: float, fy: float | None = None) -> PinholeCamera:
        """Principal point at the image centre ((W − 1)/2, (H − 1)/2)."""
        return cls(width, height, fx, fx if fy is None else fy, (width - 1) / 2, (height - 1) / 2)

    def strided(self, stride: int) -> PinholeCamera:
        """The camera of every ``stride``-th pixel in each direction (pixels 0, s, 2s, …): pixel
        u' = u / s, so fx, fy, cx, cy all scale by 1 / s."""
        if stride < 1:
            raise ValueError("stride must be ≥ 1")
        s = float(stride)
        return PinholeCamera(-(-self.width // stride), -(-self.height // stride), self.fx / s, self.fy / s,
                             self.cx / s, self.cy / s)

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy): the wire contract's ``intrinsics``."""
        return (float(self.fx), float(self.fy), float(self.cx), float(self.cy))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def rays(self, dtype: type = np.float32) -> np.ndarray:
        """(H, W, 3) camera-frame ray of each pixel, with z = 1."""
        u = (np.arange(self.width, dtype=np.float64) - self.cx) / self.fx
        v = (np.arange(self.height, dtype=np.float64) - self.cy) / self.fy
        uu, vv = np.meshgrid(u, v)
        return np.stack([uu, vv, np.ones_like(uu)], axis=-1).astype(dtype)

    def unit_rays(self) -> np.ndarray:
        """(H, W, 3) float64 unit ray directions in the camera frame."""
        d = self.rays(np.float64)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (…, 2) of camera-frame points and whether each is in front (z > 0)."""
        z = points[..., 2]
        front = z > 1e-9
        zs = np.where(front, z, 1.0)
        uv = np.stack([self.fx * points[..., 0] / zs + self.cx, self.fy * points[..., 1] / zs + self.cy], axis=-1)
        return uv, front

    def unproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points (…, 3) at pixel coordinates ``uv`` (…, 2) and depths z (…)."""
        uv = np.asarray(uv, np.float64)
        z = np.asarray(depth, np.float64)
        return np.stack([(uv[..., 0] - self.cx) / self.fx * z, (uv[..., 1] - self.cy) / self.fy * z, z], axis=-1)
