"""The ``rgbd`` backend: a depth camera and the robot's odometry instead of a SLAM server.

For robots without a GPU (the LIMO Pro carries an Orbbec Dabai), each depth image on
``camera/depth`` (``DepthImage``, registered to the RGB image of the same stamp) becomes a
pointmap by back-projection through its pinhole intrinsics,

    X(u, v) = z(u, v) · ((u − c_x)/f_x, (v − c_y)/f_y, 1),

posed by odometry: ``T_WC = T_WB(t) · T_BC``, with ``T_WB`` the ``state`` nearest in time to the
image and ``T_BC`` the camera extrinsic (``geometry.camera.T_base_camera`` of a ``CameraMount``, from
the node's settings: position in the base frame, roll / pitch / yaw of the optical axis; pitch > 0
looks down). Labels come from a ``Labeller`` (EfficientViT) when one is installed, otherwise every
pixel gets one configurable class, so the geometry still protects at that class's margin. Confidence
is ``confidence`` (``CERTAIN_CONFIDENCE``: measured, not inferred) where the depth is in (0, ``max_depth``], else 0.

Every frame is an independent measurement: messages carry no ``kind`` and the mapper integrates
each one as it comes (there are no keyframes to correct).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import CERTAIN_CONFIDENCE, DepthImage, Image, PerceptionFrame, RobotState
from riskfield.protocol.messages import Header
from riskfield.protocol.platforms import LIMO, CameraMount

from ..geometry.camera import PinholeCamera, T_base_camera
from ..geometry.transforms import quat_to_matrix
from .backend import Labeller, image_rgb


def state_pose(state: RobotState) -> np.ndarray:
    """4x4 base → world of a ``RobotState`` (quaternion xyzw)."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = quat_to_matrix(state.orientation), state.position
    return T


def back_project(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(H, W) depth → (H, W, 3) camera-frame points, ``depth · ray`` (zero where the depth is 0)."""
    h, w = depth.shape
    rays = PinholeCamera(w, h, fx, fy, cx, cy).rays(np.float32)
    return rays * np.asarray(depth, np.float32)[..., None]


@dataclass(frozen=True)
class RgbdConfig:
    camera: CameraMount = LIMO.camera  # the node passes its calibration (camera_position, camera_rpy_deg)
    label: int = 0  # ADE20K index for every pixel when there is no labeller ("wall")
    confidence: float = CERTAIN_CONFIDENCE  # a depth camera's valid pixel is measured, not inferred
    max_depth: float = 6.0
    max_state_age_s: float = 0.2  # the nearest state must be this close to the image's stamp
    frame_id: str = "map"


class Odometry:
    """The last robot states (``state``), and the base pose nearest in time to an image."""

    def __init__(self, max_age_s: float = 0.2, keep: int = 64):
        self.max_age_s = max_age_s
        self.states: deque[tuple[int, np.ndarray]] = deque(maxlen=keep)

    def on_state(self, state: RobotState) -> None:
        self.states.append((int(state.header.stamp_ns), state_pose(state)))

    def pose_at(self, stamp_ns: int) -> np.ndarray:
        """The base pose of the state nearest in time to ``stamp_ns``."""
        if not self.states:
            raise ValueError("no robot state yet (odometry on the state key poses the camera)")
        t, T = min(self.states, key=lambda s: abs(s[0] - stamp_ns))
        if abs(t - stamp_ns) > self.max_age_s * 1e9:
            raise ValueError(f"the nearest robot state is {abs(t - stamp_ns) / 1e6:.0f} ms from the image")
        return T


class RgbdBackend:
    needs_truth = False
    needs_depth = True

    def __init__(self, config: RgbdConfig | None = None, labeller: Labeller | None = None):
        self.config = config or RgbdConfig()
        self.labeller = labeller
        self.T_BC = T_base_camera(self.config.camera)
        self.odometry = Odometry(self.config.max_state_age_s)
        self.frames = 0

    def on_state(self, state: RobotState) -> None:
        self.odometry.on_state(state)

    def pose_at(self, stamp_ns: int) -> np.ndarray:
        return self.odometry.pose_at(stamp_ns)

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
