"""CLF-based nominal goal-reaching controllers (the reference the safety filter corrects).

The paper generates the autonomous-navigation reference "from a Control Lyapunov Function
(CLF)-based nominal controller following coffey2023reactive". Both laws below are closed-form
(no optimisation): each comes with a Lyapunov function ``V`` whose derivative along the
closed loop is shown to be non-positive, and saturation is applied in a way that keeps that
property (or, where it cannot, says so).

Unicycle (LIMO), polar coordinates
----------------------------------
With the robot at ``p``, heading ``θ`` and the goal ``g``: distance ``ρ = ‖g − p‖`` and bearing
error ``α = wrap(atan2(g − p) − θ)``. The unicycle ``ṗ = v(cos θ, sin θ)``, ``θ̇ = ω`` gives

    ρ̇ = −v cos α,        α̇ = −ω + v sin α / ρ.

Take ``V = ½ρ² + ½α²`` and the law (Aicardi et al. 1995 without the final-heading term)

    v = sat_v(k_ρ ρ cos α)     (forward only: v ≥ 0 unless reversing is allowed),
    ω = k_α α + v sin α / ρ.

Then ``α̇ = −k_α α`` exactly and ``ρ ρ̇ = −ρ v cos α ≤ 0`` because ``v`` has the sign of
``cos α`` (or is 0), so ``V̇ = −ρ v cos α − k_α α² ≤ 0`` whatever the linear saturation.
``v / ρ ≤ k_ρ`` keeps ``ω`` bounded at the goal. Only the final clamp of ``ω`` to
``±w_max`` can slow the decrease of ``α`` (never reverse it, since it keeps the sign).

Double integrator (3-D), cascaded PD
------------------------------------
``ṗ = v``, ``v̇ = u``, error ``e = p − g``. Unsaturated, the law is the PD ``u = −k_p e − k_d v``
whose energy ``V = ½k_p‖e‖² + ½‖v‖²`` has ``V̇ = −k_d‖v‖² ≤ 0``; the only invariant set with
``V̇ = 0`` is ``e = 0, v = 0`` (``v ≡ 0 ⇒ u ≡ 0 ⇒ e = 0``), so LaSalle gives convergence.
It is written as a velocity demand tracked by an acceleration loop,

    v_des = sat_vmax(−(k_p / k_d) e),      u = sat_amax(k_d (v_des − v)),

which is identical to the PD law while no limit is active and bounds the cruise speed by
``v_max`` and the acceleration by ``a_max`` (the norms, so the direction is kept) otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geometry.transforms import wrap_angle


def clip_norm(x: np.ndarray, limit: float) -> np.ndarray:
    """``x`` scaled down (direction kept) so that ``‖x‖ ≤ limit``."""
    n = float(np.linalg.norm(x))
    return x * (limit / n) if n > limit else x


@dataclass(frozen=True)
class UnicycleCLF:
    """Polar-coordinate CLF law for a unicycle; ``command`` returns ``(v, ω)``."""

    k_rho: float = 0.8
    k_alpha: float = 2.0
    v_max: float = 0.4
    w_max: float = 1.5
    allow_reverse: bool = False

    def command(self, position: np.ndarray, yaw: float, goal: np.ndarray) -> tuple[float, float]:
        dx, dy = float(goal[0] - position[0]), float(goal[1] - position[1])
        rho = math.hypot(dx, dy)
        if rho < 1e-9:
            return 0.0, 0.0
        alpha = wrap_angle(math.atan2(dy, dx) - yaw)
        reversing = self.allow_reverse and abs(alpha) > math.pi / 2
        if reversing:
            # Drive backwards: the rear is the "front" — same law with the bearing of the rear.
            alpha = wrap_angle(alpha + math.pi)
        v = self.k_rho * rho * math.cos(alpha)
        v = min(max(v, 0.0), self.v_max)  # v ≥ 0 only where cos α > 0, which keeps ρ̇ ≤ 0
        w = self.k_alpha * alpha + v * math.sin(alpha) / rho
        w = min(max(w, -self.w_max), self.w_max)
        return (-v if reversing else v), w

    def lyapunov(self, position: np.ndarray, yaw: float, goal: np.ndarray) -> float:
        """``V = ½ρ² + ½α²`` (forward driving)."""
        dx, dy = float(goal[0] - position[0]), float(goal[1] - position[1])
        rho = math.hypot(dx, dy)
        alpha = wrap_angle(math.atan2(dy, dx) - yaw) if rho > 1e-9 else 0.0
        return 0.5 * rho * rho + 0.5 * alpha * alpha


@dataclass(frozen=True)
class PointMassCLF:
    """Cascaded PD law for ``ṗ = v, v̇ = u`` in any dimension; ``command`` returns ``u``."""

    k_p: float = 1.0
    k_d: float = 1.6
    v_max: float = 0.5
    a_max: float = 1.0

    def desired_velocity(self, position: np.ndarray, goal: np.ndarray) -> np.ndarray:
        e = np.asarray(position, dtype=float) - np.asarray(goal, dtype=float)
        return clip_norm(-(self.k_p / self.k_d) * e, self.v_max)

    def command(self, position: np.ndarray, velocity: np.ndarray, goal: np.ndarray) -> np.ndarray:
        v_des = self.desired_velocity(position, goal)
        return clip_norm(self.k_d * (v_des - np.asarray(velocity, dtype=float)), self.a_max)

    def command_batch(self, position: np.ndarray, velocity: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """``command`` for N robots at once (rows), used by vectorised roll-outs."""
        e = np.asarray(position, dtype=float) - np.asarray(goal, dtype=float)
        v_des = _clip_rows(-(self.k_p / self.k_d) * e, self.v_max)
        return _clip_rows(self.k_d * (v_des - velocity), self.a_max)

    def lyapunov(self, position: np.ndarray, velocity: np.ndarray, goal: np.ndarray) -> float:
        """Energy ``V = ½k_p‖p − g‖² + ½‖v‖²`` of the unsaturated law."""
        e = np.asarray(position, dtype=float) - np.asarray(goal, dtype=float)
        v = np.asarray(velocity, dtype=float)
        return float(0.5 * self.k_p * e @ e + 0.5 * v @ v)


def _clip_rows(x: np.ndarray, limit: float) -> np.ndarray:
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    return x * np.minimum(1.0, limit / np.maximum(n, 1e-12))
