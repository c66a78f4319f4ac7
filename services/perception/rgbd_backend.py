"""The ``rgbd`` backend: a depth camera and the robot's odometry instead of a SLAM server.

For robots without a GPU (the LIMO Pro carries an Orbbec Dabai), each depth image on
``camera/depth`` (``DepthImage``, registered to the RGB image of the same stamp) becomes a
pointmap by back-projection through its pinhole intrinsics,

    X(u, v) = z(u, v) · ((u − c_x)/f_x, (v − c_y)/f_y, 1),

posed by odometry: ``T_WC = T_WB(t) · T_BC``, with ``T_WB`` the ``state`` nearest in time to the
image and ``T_BC`` the camera extrinsic (settings: position in the base frame, roll / pitch / yaw
of the optical axis; pitch > 0 looks down). Labels come from a ``Labeller`` (EfficientViT) when one
is installed, otherwise every pixel gets one configurable class, so the geometry still protects
at that class's margin. Confidence is ``confidence`` where the depth is in (0, ``max_depth``], else 0.

Every frame is an independent measurement: messages carry no ``kind`` and the mapper integrates
each one as it comes (there are no keyframes to correct).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import DepthImage, Image, PerceptionFrame, RobotState
from riskfield.protocol.messages import Header

from .backend import Labeller, image_rgb
from .mast3r_backend import sim3_pose

#: Base (x forward, y left, z up) ← optical (x right, y down, z forward), looking straight ahead.
R_BASE_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def T_base_camera(position: tuple[float, float, float] = (0.15, 0.0, 0.1),
                  rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Camera (optical) → base: ``[R_z(yaw)·R_y(pitch)·R_x(roll)·R_base_optical | position]``."""
    r, p, y = (math.radians(a) for a in rpy_deg)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx @ R_BASE_OPTICAL
    T[:3, 3] = position
    return T


def state_pose(state: RobotState) -> np.ndarray:
    """4x4 base → world of a ``RobotState`` (quaternion xyzw)."""
    T, _ = sim3_pose(np.array([*state.position, *state.orientation, 1.0]))
    return T


def back_project(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(H, W) depth → (H, W, 3) camera-frame points (zero where the depth is 0)."""
    h, w = depth.shape
    z = np.asarray(depth, np.float32)
    u = ((np.arange(w, dtype=np.float32) - cx) / fx)[None, :]
    v = ((np.arange(h, dtype=np.float32) - cy) / fy)[:, None]
    out = np.empty((h, w, 3), np.float32)
    out[..., 0] = z * u
    out[..., 1] = z * v
    out[..., 2] = z
    return out


@dataclass(frozen=True)
class RgbdConfig:
    camera_position: tuple[float, float, float] = (0.15, 0.0, 0.1)
    camera_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    label: int = 0  # ADE20K index for every pixel when there is no labeller ("wall")
    confidence: float = 1.0
    max_depth: float = 6.0
    max_state_age_s: float = 0.2  # the nearest state must be this close to the image's stamp
    frame_id: str = "map"


class RgbdBackend:
    needs_truth = False
    needs_depth = True

    def __init__(self, config: RgbdConfig | None = None, labeller: Labeller | None = None):
        self.config = config or RgbdConfig()
        self.labeller = labeller
        self.T_BC = T_base_camera(self.config.camera_position, self.config.camera_rpy_deg)
        self.states: deque[tuple[int, np.ndarray]] = deque(maxlen=64)
        self.frames = 0

    def on_state(self, state: RobotState) -> None:
        self.states.append((int(state.header.stamp_ns), state_pose(state)))

    def pose_at(self, stamp_ns: int) -> np.ndarray:
        """The base pose of the state nearest in time to ``stamp_ns``."""
        if not self.states:
            raise ValueError("no robot state yet (odometry on the state key poses the depth camera)")
        t, T = min(self.states, key=lambda s: abs(s[0] - stamp_ns))
        if abs(t - stamp_ns) > self.config.max_state_age_s * 1e9:
            raise ValueError(f"the nearest robot state is {abs(t - stamp_ns) / 1e6:.0f} ms from the image")
        return T

    def process(self, image: Image | None, depth: DepthImage | None, stamp_ns: int) -> list[PerceptionFrame]:
        if image is None or depth is None:
            return []
        c = self.config
        z = np.asarray(depth.depth, np.float32)
        if z.shape != (image.height, image.width):
            raise ValueError(f"depth is {z.shape[1]}x{z.shape[0]}, the image {image.width}x{image.height}")
        T_WC = self.pose_at(stamp_ns) @ self.T_BC
        valid = np.isfinite(z) & (z > 0) & (z <= c.max_depth)
        z = np.where(valid, z, np.float32(0.0))
        points = back_project(z, depth.fx, depth.fy, depth.cx, depth.cy)
        if self.labeller is not None:
            labels = np.asarray(self.labeller(image_rgb(image)), np.uint16)
            if labels.shape != z.shape:
                raise ValueError(f"labeller returned {labels.shape}, the frame is {z.shape}")
        else:
            labels = np.full(z.shape, c.label, np.uint16)
        self.frames += 1
        return [PerceptionFrame(header=Header(stamp_ns=stamp_ns, frame_id=c.frame_id), T_WC=T_WC, points=points,
                                confidence=np.where(valid, np.float32(c.confidence), np.float32(0.0)),
                                labels=labels, keyframe_id=self.frames - 1)]
