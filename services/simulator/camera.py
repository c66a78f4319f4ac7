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
from .kernels import HAVE_NUMBA
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


#: Any uint16 label → RGB in [0, 1] (black for labels outside ADE20K, e.g. "nothing hit").
_LUT = np.zeros((65536, 3), np.float32)
_LUT[: ade20k.NUM_CLASSES] = PALETTE[: ade20k.NUM_CLASSES]


def class_colour(label: np.ndarray) -> np.ndarray:
    return _LUT[np.asarray(label, np.uint16)]


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


def _rotate(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    # Not ``v @ R.T``: a BLAS gemm with a 3-wide inner dimension stalls on a busy machine.
    # (geometry.transforms.transform_points is the same product plus a translation, in float64;
    # this one keeps the rays' float32 and skips the translation, once per pixel per frame.)
    out = np.empty_like(v)
    for i in range(3):
        out[..., i] = R[i, 0] * v[..., 0] + R[i, 1] * v[..., 1] + R[i, 2] * v[..., 2]
    return out


@dataclass
class Renderer:
    camera: PinholeCamera = field(default_factory=PinholeCamera)
    ambient: float = 0.25
    max_depth: float = 50.0
    #: shade in one compiled pass (``kernels.shade_kernel``, the same bytes); False: numpy
    compiled: bool = HAVE_NUMBA

    def __post_init__(self) -> None:
        self._rays = self.camera.rays()
        self._inv_len = (1.0 / np.linalg.norm(self._rays, axis=-1)).astype(np.float32)

    def render(self, snapshot: Snapshot, T_WC: np.ndarray) -> Render:
        """Cast one ray per pixel from the camera pose ``T_WC`` (4x4 camera → world)."""
        T_WC = np.asarray(T_WC, np.float64)
        R = T_WC[:3, :3].astype(np.float32)
        if self.compiled and not snapshot.empty:
            return self._render_compiled(snapshot, T_WC, R)
        dirs = _rotate(R, self._rays)
        hits = snapshot.cast(T_WC[:3, 3].astype(np.float32), dirs)
        ok = hits.t <= self.max_depth  # inf (no hit) fails this too
        depth = np.where(ok, hits.t, np.float32(0.0))
        points = self._rays * depth[..., None]
        labels = np.where(ok, hits.label, NO_LABEL)
        normals = hits.normal  # zero where nothing was hit
        normals[~ok] = 0.0  # and beyond max_depth
        # Lambert: head-light |n·view| (both faces lit) plus light from above.
        n_dot_d = normals[..., 0] * dirs[..., 0] + normals[..., 1] * dirs[..., 1] + normals[..., 2] * dirs[..., 2]
        lambert = np.abs(n_dot_d) * self._inv_len
        sky = np.clip(normals[..., 2], 0.0, 1.0)
        shade = (255.0 * self.ambient) + (255.0 * (1.0 - self.ambient)) * np.minimum(0.8 * lambert + 0.2 * sky, 1.0)
        rgb = (class_colour(labels) * shade[..., None] + 0.5).astype(np.uint8)  # black where nothing was hit
        return Render(
            rgb=rgb,
            depth=depth,
            points=points,
            labels=labels,
            normals=normals,
            object=np.where(ok, hits.object, -1).astype(np.int32),
            T_WC=T_WC,
        )

    def _render_compiled(self, snapshot: Snapshot, T_WC: np.ndarray, R: np.ndarray) -> Render:
        from .kernels import pack_rays_kernel, shade_kernel

        h, w = self._rays.shape[:2]
        n = h * w
        rays = np.empty((n, 6), np.float32)
        pack_rays_kernel(R, T_WC[:3, 3].astype(np.float32), self._rays.reshape(-1, 3), rays)
        out = snapshot.cast_packed(rays)
        dirs = rays[:, 3:]
        depth, labels, obj = np.empty(n, np.float32), np.empty(n, np.uint16), np.empty(n, np.int32)
        points, normals, rgb = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty((n, 3), np.uint8)
        shade_kernel((out["t_hit"], out["geometry_ids"], out["primitive_ids"], out["primitive_normals"]),
                     (self._rays.reshape(-1, 3), dirs, self._inv_len.reshape(-1)),
                     (snapshot.offsets, snapshot.object_index, snapshot.triangle_labels, _LUT),
                     (float(self.max_depth), int(NO_LABEL), 255.0 * self.ambient, 255.0 * (1.0 - self.ambient)),
                     (depth, points, labels, normals, rgb, obj))
        return Render(rgb=rgb.reshape(h, w, 3), depth=depth.reshape(h, w), points=points.reshape(h, w, 3),
                      labels=labels.reshape(h, w), normals=normals.reshape(h, w, 3), object=obj.reshape(h, w),
                      T_WC=T_WC)
