"""Analytic scenes rendered as pointmaps, for tests and the benchmark (no simulator needed).

A pinhole camera (OpenCV convention: x right, y down, z forward) looks at planes, axis-aligned
boxes and spheres; each pixel's ray is intersected exactly, so the true surface — and the
true distance to it — is known in closed form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Plane:
    normal: tuple[float, float, float]
    offset: float  # points x with n·x = offset
    label: int

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        n = np.asarray(self.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        den = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.offset - o @ n) / den
        return np.where((np.abs(den) > 1e-12) & (t > 0), t, np.inf)

    def sdf(self, x: np.ndarray) -> np.ndarray:
        """Unsigned distance to the plane (a plane has no inside)."""
        n = np.asarray(self.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        return np.abs(x @ n - self.offset)


@dataclass(frozen=True)
class Box:
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    label: int

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            ta, tb = (lo - o) * inv, (hi - o) * inv
        ta = np.nan_to_num(ta, nan=-np.inf)
        tb = np.nan_to_num(tb, nan=np.inf)
        tn = np.minimum(ta, tb).max(axis=-1)
        tf = np.maximum(ta, tb).min(axis=-1)
        return np.where((tn <= tf) & (tn > 0), tn, np.inf)

    def sdf(self, x: np.ndarray) -> np.ndarray:
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
        q = np.abs(x - c) - h
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


@dataclass(frozen=True)
class Sphere:
    centre: tuple[float, float, float]
    radius: float
    label: int

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        oc = o - np.asarray(self.centre)
        b = np.sum(d * oc, axis=-1)
        c = np.sum(oc * oc, axis=-1) - self.radius**2
        disc = b * b - c
        t = -b - np.sqrt(np.maximum(disc, 0.0))
        return np.where((disc >= 0) & (t > 0), t, np.inf)

    def sdf(self, x: np.ndarray) -> np.ndarray:
        return np.linalg.norm(x - np.asarray(self.centre), axis=-1) - self.radius


Primitive = Plane | Box | Sphere


@dataclass(frozen=True)
class Camera:
    width: int = 512
    height: int = 384
    fx: float = 400.0
    fy: float = 400.0

    @property
    def rays(self) -> np.ndarray:
        """Unit ray directions in the camera frame, (H, W, 3)."""
        u, v = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
        d = np.stack([(u - self.width / 2) / self.fx, (v - self.height / 2) / self.fy, np.ones_like(u)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


def look_at(eye: np.ndarray, target: np.ndarray, up: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> np.ndarray:
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


def render(scene: list[Primitive], T_WC: np.ndarray, camera: Camera = Camera(),
           confidence: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pointmap (H, W, 3) float32 in the camera frame, confidence (H, W), labels (H, W) uint16.

    Pixels that hit nothing get confidence 0 and a zero point (the mapper skips them).
    """
    d_cam = camera.rays
    R, o = T_WC[:3, :3], T_WC[:3, 3]
    d_world = d_cam @ R.T
    t = np.full(d_cam.shape[:2], np.inf)
    labels = np.zeros(d_cam.shape[:2], dtype=np.uint16)
    for prim in scene:
        ti = prim.intersect(o, d_world)
        closer = ti < t
        t = np.where(closer, ti, t)
        labels[closer] = prim.label
    hit = np.isfinite(t)
    points = np.where(hit[..., None], d_cam * np.where(hit, t, 0.0)[..., None], 0.0).astype(np.float32)
    conf = np.where(hit, confidence, 0.0).astype(np.float32)
    return points, conf, labels


def scene_distance(scene: list[Primitive], x: np.ndarray) -> np.ndarray:
    """Signed distance from points to the union of the primitives (planes unsigned)."""
    return np.min(np.stack([p.sdf(x) for p in scene]), axis=0)


def orbit(target: np.ndarray, n: int = 5, radius: float = 0.2, height: float = 0.3,
          spread: float = 0.6) -> list[np.ndarray]:
    """``n`` camera poses on an arc of ``radius`` around the origin at ``height``, looking at ``target``."""
    out = []
    for a in np.linspace(-spread, spread, n):
        eye = np.array([-radius * np.cos(a), radius * np.sin(a), height])
        out.append(look_at(eye, np.asarray(target, dtype=np.float64)))
    return out
