"""The simulated forward RGB camera: a renderer that ray-casts the scene into RGB, depth, a
camera-frame pointmap and ground-truth labels.

The pinhole model and its conventions (OpenCV; the pointmap is ``depth · ray``) are
``riskfield.services.geometry.camera.PinholeCamera``; where the camera sits on the robot is the
scenario's mount (``scenario.CameraSpec.camera_mount``, the LIMO's ``protocol.platforms.LIMO.camera``
unless the scenario says otherwise), posed by ``geometry.camera.T_base_camera``.

The default image is 512×384 — what MASt3R-SLAM works at (a 640×480 frame resized and cropped)
— with a 90° horizontal field of view.

RGB is the class colour times Lambert shading by the surface normal (a head-light term, so every
visible surface is lit, plus a sky-light term from above): enough texture for a segmentation
network to separate classes and for a human to read the image.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field

import numpy as np

from riskfield.protocol import ade20k

from ..geometry.camera import PinholeCamera
from ..runtime.jit import require_numba
from . import kernels
from .scene import NO_LABEL, Snapshot


def _palette() -> np.ndarray:
    # Distinct, deterministic colours: golden-ratio hue steps, three saturation levels.
    out = np.zeros((ade20k.NUM_CLASSES + 1, 3), np.float32)
    for i in range(ade20k.NUM_CLASSES):
        h = (i * 0.6180339887) % 1.0
        s = 0.45 + 0.25 * (i % 3)
        out[i] = colorsys.hsv_to_rgb(h, s, 0.95)
    out[-1] = (0.0, 0.0, 0.0)  # nothing hit: black
    return out


#: Class index → RGB in [0, 1]; index ``NUM_CLASSES`` (and any unknown label) is black.
PALETTE = _palette()


#: Any uint16 label → RGB in [0, 1] (black for labels outside ADE20K, e.g. "nothing hit"): the
#: shading kernel's colour table.
_LUT = np.zeros((65536, 3), np.float32)
_LUT[: ade20k.NUM_CLASSES] = PALETTE[: ade20k.NUM_CLASSES]


@dataclass
class Render:
    """One rendered frame. ``points`` is the camera-frame pointmap (zeros where nothing was
    hit), ``depth`` its z (0 where nothing), ``labels`` ADE20K indices (``NO_LABEL`` where
    nothing), ``normals`` world-frame surface normals, ``object`` the scene object index (-1)."""

    rgb: np.ndarray
    depth: np.ndarray
    points: np.ndarray
    labels: np.ndarray
    normals: np.ndarray
    object: np.ndarray
    T_WC: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.depth > 0


@dataclass
class Renderer:
    camera: PinholeCamera = field(default_factory=PinholeCamera)
    ambient: float = 0.25
    max_depth: float = 50.0

    def __post_init__(self) -> None:
        require_numba("the renderer")
        self._rays = self.camera.rays()
        self._inv_len = (1.0 / np.linalg.norm(self._rays, axis=-1)).astype(np.float32)

    def render(self, snapshot: Snapshot, T_WC: np.ndarray) -> Render:
        """Cast one ray per pixel from the camera pose ``T_WC`` (4x4 camera → world) and shade the
        hits in one compiled pass (``kernels.shade_kernel``); in an empty scene every ray misses."""
        T_WC = np.asarray(T_WC, np.float64)
        R = T_WC[:3, :3].astype(np.float32)
        h, w = self._rays.shape[:2]
        n = h * w
        rays = np.empty((n, 6), np.float32)
        kernels.pack_rays_kernel(R, T_WC[:3, 3].astype(np.float32), self._rays.reshape(-1, 3), rays)
        out = snapshot.cast_packed(rays) if not snapshot.empty else _misses(n)
        dirs = rays[:, 3:]
        depth, labels, obj = np.empty(n, np.float32), np.empty(n, np.uint16), np.empty(n, np.int32)
        points, normals, rgb = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty((n, 3), np.uint8)
        kernels.shade_kernel((out["t_hit"], out["geometry_ids"], out["primitive_ids"], out["primitive_normals"]),
                             (self._rays.reshape(-1, 3), dirs, self._inv_len.reshape(-1)),
                             (snapshot.offsets, snapshot.object_index, snapshot.triangle_labels, _LUT),
                             (float(self.max_depth), int(NO_LABEL), 255.0 * self.ambient, 255.0 * (1.0 - self.ambient)),
                             (depth, points, labels, normals, rgb, obj))
        return Render(rgb=rgb.reshape(h, w, 3), depth=depth.reshape(h, w), points=points.reshape(h, w, 3),
                      labels=labels.reshape(h, w), normals=normals.reshape(h, w, 3), object=obj.reshape(h, w),
                      T_WC=T_WC)


def _misses(n: int) -> dict[str, np.ndarray]:
    """open3d's ``cast_rays`` output for ``n`` rays that hit nothing (an empty scene has no
    raycaster to ask): ``t_hit`` inf, the ids and normals never read."""
    return {"t_hit": np.full(n, np.inf, np.float32), "geometry_ids": np.zeros(n, np.uint32),
            "primitive_ids": np.zeros(n, np.uint32), "primitive_normals": np.zeros((n, 3), np.float32)}
