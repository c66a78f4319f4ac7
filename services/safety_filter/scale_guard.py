"""The filter's answer to a map of uncertain scale: a conservative distance and a speed cap.

Perception publishes on ``perception/alignment`` how well it knows the similarity from its SLAM
world into the odometry frame (``Alignment``: the scale's relative σ, the fit's RMS residual).
An obstacle mapped at range d from the camera that saw it is off by about σ·d, plus the residual.
So, once an alignment has arrived, the filter reads the field shrunk by that much:

    d' = d − k · (σ · clip(d, 0, max_range) + residual)

(k = ``k_sigma``; for 0 ≤ d ≤ max_range, d' = (1 − kσ)·d − k·residual: still a distance field, its
slope below 1). While the estimate has not converged (``Alignment.converged`` false) or stopped
coming (older than ``timeout_s``), the reference's speed is also capped at ``speed_cap``, linear
and angular scaled together so the path's curvature stays. A stack without SLAM never publishes an
alignment, and then nothing changes. Plain objects: the supervisor calls them on every step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import Alignment

from ..fields import DistanceField, EsdfField, FieldSample

#: the margin's parameters are rounded up to these steps, so the shrunk grid is rebuilt only when the
#: map or the estimate changes by that much (conservative: never rounded down)
SIGMA_STEP = 0.0025
RESIDUAL_STEP = 0.001


@dataclass(frozen=True)
class ScaleGuardConfig:
    k_sigma: float = 2.0
    speed_cap: float = 0.2  # m/s
    max_range: float = 4.0  # m
    timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if not (self.k_sigma >= 0 and self.speed_cap >= 0 and self.max_range > 0 and self.timeout_s > 0):
            raise ValueError("scale guard: k_sigma, speed_cap ≥ 0; max_range, timeout_s > 0")


class ShrunkField:
    """Any distance field read as d − k·(σ·clip(d, 0, max_range) + residual)."""

    def __init__(self, base: DistanceField, a: float, b: float, max_range: float):
        self.base, self.a, self.b, self.max_range = base, a, b, max_range  # a = k·σ, b = k·residual

    @property
    def groups(self):  # type: ignore[no-untyped-def]
        return self.base.groups

    def query(self, points: np.ndarray, hessian: bool = False) -> FieldSample:
        s = self.base.query(points, hessian)
        d = np.asarray(s.distance, np.float64)
        ramp = (d > 0) & (d < self.max_range)
        factor = np.where(ramp, 1.0 - self.a, 1.0)
        return FieldSample(shrink(d, self.a, self.b, self.max_range), s.gradient * factor[:, None],
                           None if s.hessian is None else s.hessian * factor[:, None, None], s.risk_group, s.inside)


def shrink(d: np.ndarray, a: float, b: float, max_range: float) -> np.ndarray:
    return d - (a * np.clip(d, 0.0, max_range) + b)


class ScaleGuard:
    """The newest alignment and what it does to the filter's field and speed (module doc)."""

    def __init__(self, config: ScaleGuardConfig | None = None):
        self.config = config or ScaleGuardConfig()
        self.alignment: Alignment | None = None
        self.at = -math.inf
        self._cache: tuple[object, float, float, DistanceField] | None = None

    def on_alignment(self, msg: Alignment, now: float) -> None:
        self.alignment, self.at = msg, now

    @property
    def active(self) -> bool:
        return self.alignment is not None

    def uncertain(self, now: float) -> bool:
        a = self.alignment
        return a is not None and (not a.converged or now - self.at > self.config.timeout_s)

    def params(self) -> tuple[float, float]:
        """(k·σ, k·residual), rounded up (``SIGMA_STEP``, ``RESIDUAL_STEP``); (0, 0) without an alignment."""
        a = self.alignment
        if a is None:
            return 0.0, 0.0
        k = self.config.k_sigma
        sigma = math.ceil(min(a.scale_sigma, 1.0) / SIGMA_STEP) * SIGMA_STEP
        residual = math.ceil(a.residual / RESIDUAL_STEP) * RESIDUAL_STEP
        return min(k * sigma, 0.95), k * residual

    def field(self, field: DistanceField) -> DistanceField:
        """The field the filter reads: ``field`` shrunk by the scale's uncertainty."""
        a, b = self.params()
        if a == 0.0 and b == 0.0:
            return field
        c = self._cache
        if c is not None and c[0] is field and c[1] == a and c[2] == b:
            return c[3]
        out: DistanceField
        if isinstance(field, EsdfField):
            # A grid of its own, so the compiled step reads it as it reads any map.
            out = type(field)(shrink(field.distance, a, b, self.config.max_range).astype(field.distance.dtype),
                              field.origin, field.voxel_size, field.risk_groups, field.groups, field.max_distance,
                              field.unknown_is_occupied, check=False, interpolation=field.interpolation)
        else:
            out = ShrunkField(field, a, b, self.config.max_range)
        self._cache = (field, a, b, out)
        return out

    def margin_at(self, shrunk: float) -> float:
        """How much was taken off at a point whose shrunk distance is ``shrunk`` (for the status)."""
        a, b = self.params()
        if a == 0.0 and b == 0.0:
            return 0.0
        d = (shrunk + b) / (1.0 - a)
        if d > self.config.max_range:
            d = shrunk + a * self.config.max_range + b
        return max(float(a * min(max(d, 0.0), self.config.max_range) + b), 0.0)

    def cap(self, linear: np.ndarray, angular: np.ndarray, now: float) -> tuple[np.ndarray, np.ndarray, float | None]:
        """(linear, angular) with the speed capped while uncertain, and the cap (None: none)."""
        if not self.uncertain(now):
            return linear, angular, None
        v = float(np.linalg.norm(linear))
        cap = self.config.speed_cap
        if v > cap:
            f = cap / v
            return linear * f, angular * f, cap
        return linear, angular, cap
