"""The one family of closed-form shapes: planes, axis-aligned boxes and spheres.

Each shape can be

* **ray-cast**: ``intersect(o, d)`` is the ray parameter ``t > 0`` of the first hit of
  ``o + t·d`` (``inf`` for none), so :func:`render` draws exact synthetic pointmaps;
* **measured**: ``distance(x)`` is the exact signed distance (negative inside), with its
  ``gradient(x)`` (the outward unit normal of the nearest surface point) and ``hessian(x)``
  (the curvature term ``(P − n nᵀ)/ρ``, P the projector onto the directions ρ is measured in).
  The analytic distance fields (:mod:`riskfield.services.fields.analytic`) are unions of them.

``label`` is the integer a shape reports: the semantic class a render writes into the label
image, or the risk group an analytic field reports. Spelling: ``center`` (numpy/open3d).

Obstacle sides: a :class:`Plane` ``n·x = offset`` is the half-space *behind* its normal
(``n·x ≤ offset`` is solid, ``distance = n·x − offset``); a ``planar`` :class:`Sphere` is the
infinite vertical cylinder through its disc (x and y only).

numpy only, so the fields package (and a robot-level install) can use it without scipy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .camera import PinholeCamera

_TINY = 1e-12


def _unit(v: Sequence[float]) -> tuple[float, float, float]:
    n = np.asarray(v, np.float64).reshape(3)
    n = n / np.linalg.norm(n)
    return float(n[0]), float(n[1]), float(n[2])


@dataclass(frozen=True)
class Plane:
    """The half-space ``n·x ≤ offset`` (``normal`` is normalised on construction)."""

    normal: tuple[float, float, float]
    offset: float
    label: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "normal", _unit(self.normal))

    @classmethod
    def through(cls, point: Sequence[float], normal: Sequence[float], label: int = 0) -> Plane:
        """The plane through ``point`` with outward ``normal`` (solid behind it)."""
        n = _unit(normal)
        return cls(n, float(np.dot(n, np.asarray(point, np.float64))), label)

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        n = np.asarray(self.normal)
        den = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.offset - o @ n) / den
        return np.where((np.abs(den) > _TINY) & (t > 0), t, np.inf)

    def distance(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, np.float64) @ np.asarray(self.normal) - self.offset

    def gradient(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, np.float64)
        return np.broadcast_to(np.asarray(self.normal), x.shape).copy()

    def hessian(self, x: np.ndarray) -> np.ndarray:
        return np.zeros((*np.shape(x)[:-1], 3, 3))


@dataclass(frozen=True)
class Sphere:
    """The ball ``|x − center| ≤ radius``; ``planar=True``: the vertical cylinder through its disc."""

    center: tuple[float, float, float]
    radius: float
    label: int = 0
    planar: bool = False

    def __post_init__(self) -> None:
        c = np.asarray(self.center, np.float64).reshape(3)
        object.__setattr__(self, "center", (float(c[0]), float(c[1]), float(c[2])))

    @property
    def mask(self) -> np.ndarray:
        """The axes the distance is measured in."""
        return np.array([1.0, 1.0, 0.0]) if self.planar else np.ones(3)

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        m = self.mask
        oc = (o - np.asarray(self.center)) * m
        dm = d * m
        a = np.sum(dm * dm, axis=-1)
        b = np.sum(dm * oc, axis=-1)
        c = np.sum(oc * oc, axis=-1) - self.radius**2
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        return np.where((a > _TINY) & (disc >= 0) & (t > 0), t, np.inf)

    def _radial(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = (np.asarray(x, np.float64) - np.asarray(self.center)) * self.mask
        rho = np.maximum(np.linalg.norm(r, axis=-1), _TINY)
        return r, rho

    def distance(self, x: np.ndarray) -> np.ndarray:
        return self._radial(x)[1] - self.radius

    def gradient(self, x: np.ndarray) -> np.ndarray:
        r, rho = self._radial(x)
        return r / rho[..., None]

    def hessian(self, x: np.ndarray) -> np.ndarray:
        r, rho = self._radial(x)
        u = r / rho[..., None]
        return (np.diag(self.mask) - u[..., :, None] * u[..., None, :]) / rho[..., None, None]


@dataclass(frozen=True)
class Box:
    """The axis-aligned box ``lo ≤ x ≤ hi``."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    label: int = 0

    @property
    def center(self) -> np.ndarray:
        return 0.5 * (np.asarray(self.lo, np.float64) + np.asarray(self.hi, np.float64))

    @property
    def half(self) -> np.ndarray:
        return 0.5 * (np.asarray(self.hi, np.float64) - np.asarray(self.lo, np.float64))

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # an axis-parallel ray: ±inf slabs
            inv = 1.0 / d
            ta, tb = (lo - o) * inv, (hi - o) * inv
        ta = np.nan_to_num(ta, nan=-np.inf)
        tb = np.nan_to_num(tb, nan=np.inf)
        tn = np.minimum(ta, tb).max(axis=-1)
        tf = np.maximum(ta, tb).min(axis=-1)
        return np.where((tn <= tf) & (tn > 0), tn, np.inf)

    def _q(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = np.asarray(x, np.float64) - self.center
        return np.abs(rel) - self.half, np.where(rel < 0, -1.0, 1.0)

    def distance(self, x: np.ndarray) -> np.ndarray:
        q, _ = self._q(x)
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """Outside: towards x from its nearest box point; inside: the normal of the nearest face."""
        q, sign = self._q(x)
        out = np.maximum(q, 0.0)
        rho = np.linalg.norm(out, axis=-1)
        inside = rho <= _TINY
        face = np.eye(3)[np.argmax(q, axis=-1)]
        g = np.where(inside[..., None], face, out / np.maximum(rho, _TINY)[..., None])
        return g * sign

    def hessian(self, x: np.ndarray) -> np.ndarray:
        """(P − n nᵀ)/ρ outside, P the projector onto the axes where x is beyond a face (zero
        before a face, where the distance is linear); zero inside."""
        q, sign = self._q(x)
        out = np.maximum(q, 0.0)
        rho = np.linalg.norm(out, axis=-1)
        u = sign * out / np.maximum(rho, _TINY)[..., None]
        P = (q > 0).astype(np.float64)[..., :, None] * np.eye(3)
        H = (P - u[..., :, None] * u[..., None, :]) / np.maximum(rho, _TINY)[..., None, None]
        return np.where((rho > _TINY)[..., None, None], H, 0.0)


Shape = Plane | Box | Sphere

#: The synthetic scenes' camera: 512×384, f = 400 px, principal point at the image centre.
SYNTHETIC_CAMERA = PinholeCamera.centred(512, 384, 400.0)


def render(scene: Sequence[Shape], T_WC: np.ndarray, camera: PinholeCamera = SYNTHETIC_CAMERA,
           confidence: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pointmap (H, W, 3) float32 in the camera frame, confidence (H, W), labels (H, W) uint16.

    Each pixel's unit ray is intersected with every shape exactly; pixels that hit nothing get
    confidence 0 and a zero point (the mapper skips them).
    """
    d_cam = camera.unit_rays()
    R, o = T_WC[:3, :3], T_WC[:3, 3]
    d_world = d_cam @ R.T
    t = np.full(d_cam.shape[:2], np.inf)
    labels = np.zeros(d_cam.shape[:2], dtype=np.uint16)
    for shape in scene:
        ti = shape.intersect(o, d_world)
        closer = ti < t
        t = np.where(closer, ti, t)
        labels[closer] = shape.label
    hit = np.isfinite(t)
    points = np.where(hit[..., None], d_cam * np.where(hit, t, 0.0)[..., None], 0.0).astype(np.float32)
    conf = np.where(hit, confidence, 0.0).astype(np.float32)
    return points, conf, labels
