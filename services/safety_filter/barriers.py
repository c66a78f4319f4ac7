"""Barrier models: the robot dynamics ẋ = f(x) + g(x) u, the barrier h(x) = d(p) - r at one or
more points p of the robot, and the affine CBF row (A u ≥ b) each point adds to the QP.

The safety function follows the paper: h = d(p) (the semantically inflated ESDF), here minus the
robot radius r and a small sampled-data margin δ (below). Every point p_i (the look-ahead point,
body points) adds one row with the class-dependent gain of the risk group of its nearest
obstacle. Gains come in a table with columns :data:`ALPHA`, :data:`ALPHA1`, :data:`ALPHA2`.

* :class:`UnicycleLookahead` — differential drive / LIMO teleoperation. State [px, py, θ],
  input [v, ω]; the look-ahead point p_L = p + L (cos θ, sin θ) moves as
  ṗ_L = J(θ) [v, ω], J = [[cos θ, -L sin θ], [sin θ, L cos θ]], giving the paper's row
  ∇d(p_L)ᵀ J(θ) [v, ω] ≥ -α_l h(p_L), with QP weights λv, λω.
* :class:`SingleIntegrator` — holonomic base, mecanum, drone velocity control, in 2-D or 3-D.
  The input is the body-frame linear velocity u (the frame of ``VelocityCommand``); the body
  turns at the reference's angular velocity ω, which the filter passes through. A point at body
  offset o moves as ṗ = R u + R (ω × o): row ∇dᵀ R u ≥ -α h - ∇dᵀ R (ω × o).
* :class:`DoubleIntegrator` — ṗ = v, v̇ = u (the paper's simulation model), with the
  high-order CBF ḧ + α₁ ḣ + α₂ h ≥ 0, i.e. ∇dᵀu + vᵀ∇²d v + α₁ ∇dᵀv + α₂ h ≥ 0.

Sampled-data margin. The CBF condition is imposed at the sampling instants only, and the input
is held for the control period T. Between samples h drifts from its linearisation by at most
½ M T² (M bounds |ḧ| for the held input: curvature of the look-ahead arc or of the field), so h
can dip below zero by at most about ½ M T / α in the worst persistent case. Enforcing the CBF on
h - δ keeps the true h = d - r non-negative when δ exceeds that dip; with the LIMO bounds
(|v| ≤ 1 m/s, |ω| ≤ 2 rad/s, L = 0.25 m, T = 20 ms) the per-step bound is 0.45 mm and the
default δ = 2 cm covers gains α ≥ 0.6 with a wide margin (see the closed-loop tests). For the
HOCBF the held input enters ḧ directly, the per-step error is O(T³) and δ is ample.

The whole body. Every model carries, besides its control point(s), the discs (balls) of a
cover of its footprint (:func:`disc_cover`): body point o_i with its own radius r_i, so
h_i = d(p + R o_i) - r_i ≥ 0 for all i keeps the whole footprint out of the obstacles. Each
disc is one CBF row with the gains of the risk group of the nearest obstacle to that disc.

Stopping under bounded inputs. *Velocity-controlled* models (unicycle, single integrators)
stop by commanding zero, which the platform reaches with its deceleration a (``a_max``). The
first-order CBF bounds each point's approach speed by s ≤ α h, and the distance needed to shed
it, s²/(2a), is at most h whenever α² h ≤ 2a; since also s ≤ v_max this holds for every h iff
α ≤ 2a / v_max (for h ≥ v_max/α: v_max²/(2a) ≤ v_max/α ≤ h). The filter caps α there
(:meth:`BarrierModel.alpha_cap`), so the lag of a real stop never eats into h. u = 0 satisfies
every row with h - δ ≥ 0, so such a QP is always feasible. The *double integrator* has the
braking-distance barrier (:class:`DoubleIntegrator`, default) instead of the paper's HOCBF.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from ..fields import DistanceField, FieldSample
from ..geometry.transforms import yaw_matrix
from .state import FilterState, skew, so3_exp, so3_integral

ALPHA, ALPHA1, ALPHA2 = 0, 1, 2


def disc_cover(length: float, width: float, discs: int, capsule: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Discs on the medial axis (body x) whose union covers a length × width rectangle
    (or capsule) centred on the body origin: (offsets (k, 3), radii (k,)).

    The rectangle is cut into k equal slices of length ℓ = L/k; the disc at the centre of a slice
    with radius √((ℓ/2)² + (W/2)²) contains that slice (its farthest points are the slice's
    corners). A capsule (a W-wide rectangle of length L - W with half-disc ends) is covered the
    same way with the centres on its segment and the end discs' radius W/2 reaching its ends.
    For the LIMO (0.322 × 0.220 m, k = 3) the discs overhang the sides by 1.2 cm.
    """
    if discs < 1 or length <= 0 or width <= 0:
        raise ValueError("a footprint needs positive length and width and at least one disc")
    if capsule:
        seg = max(length - width, 0.0)
        if discs == 1 or seg == 0.0:
            return np.zeros((1, 3)), np.array([0.5 * length if seg > 0 else 0.5 * width])
        xs = np.linspace(-seg / 2, seg / 2, discs)
        r = math.hypot(0.5 * seg / (discs - 1), 0.5 * width)
        return np.stack([xs, 0 * xs, 0 * xs], axis=1), np.full(discs, r)
    sl = length / discs
    xs = -length / 2 + sl * (np.arange(discs) + 0.5)
    return np.stack([xs, 0 * xs, 0 * xs], axis=1), np.full(discs, math.hypot(0.5 * sl, 0.5 * width))


def _offsets(points: list[tuple[float, float, float]] | np.ndarray) -> np.ndarray:
    o = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if o.shape[0] == 0:
        raise ValueError("a barrier model needs at least one point")
    return o


class BarrierModel(ABC):
    """Common parts: the barrier points, h, the QP weights and the input bounds."""

    name: ClassVar[str] = ""
    needs_hessian: ClassVar[bool] = False

    def __init__(self, offsets: np.ndarray, radius: float | np.ndarray, weights: np.ndarray, lo: np.ndarray,
                 hi: np.ndarray):
        self.offsets = _offsets(offsets)
        self._offset_list = [tuple(float(v) for v in o) for o in self.offsets]
        #: r_i per point, (m,): the clearance of point i is d(p_i) - r_i.
        self.radius = np.broadcast_to(np.asarray(radius, np.float64), (self.offsets.shape[0],)).copy()
        self.weights = np.asarray(weights, np.float64)
        self.lo = np.asarray(lo, np.float64)
        self.hi = np.asarray(hi, np.float64)
        if not (np.all(self.weights > 0) and np.all(self.lo <= 0) and np.all(self.hi >= 0)):
            raise ValueError("weights must be positive and the bounds must contain zero (braking)")

    @property
    def n(self) -> int:
        """Number of inputs."""
        return self.weights.shape[0]

    @property
    def m(self) -> int:
        """Number of barrier rows (one per point)."""
        return self.offsets.shape[0]

    def _rotation(self, s: FilterState) -> np.ndarray:
        return s.rotation

    def points(self, s: FilterState) -> np.ndarray:
        """World positions of the barrier points, (m, 3)."""
        return s.position + self.offsets @ self._rotation(s).T

    def predicted_points(self, s: FilterState, u: np.ndarray, dt: float, angular: np.ndarray | None) -> np.ndarray:
        """The barrier points after dt with the input held (exact)."""
        return self.points(self.integrate(s, u, dt, angular))

    def h(self, s: FilterState, field: DistanceField) -> np.ndarray:
        """h_i = d(p_i) - r at every point (without the sampled-data margin)."""
        return field.query(self.points(s)).distance - self.radius

    @abstractmethod
    def f(self, s: FilterState) -> np.ndarray:
        """Drift of the model's state vector."""

    @abstractmethod
    def g(self, s: FilterState) -> np.ndarray:
        """Input matrix of the model's state vector."""

    @abstractmethod
    def rows(self, s: FilterState, sample: FieldSample, h: np.ndarray, gains: np.ndarray,
             angular: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """CBF rows A u ≥ b at the points: ``h`` (m,) barrier values, ``gains`` (m, 3).
        ``angular`` is the body-frame angular velocity the filter passes through."""

    @abstractmethod
    def reference(self, linear: np.ndarray, angular: np.ndarray, s: FilterState) -> np.ndarray:
        """The model input matching a body-frame velocity command."""

    @abstractmethod
    def command(self, u: np.ndarray, angular: np.ndarray, s: FilterState) -> tuple[np.ndarray, np.ndarray]:
        """Body-frame (linear, angular) velocity command of a model input."""

    def brake(self, s: FilterState) -> np.ndarray:
        """The input that stops the robot (zero velocity for velocity-controlled models)."""
        return np.zeros(self.n)

    def backup(self, s: FilterState, gradient: np.ndarray) -> np.ndarray:
        """The maximal-braking input along the field's gradient at the critical point: what the
        slack-relaxed QP must do at least as well as, row by row. Velocity-controlled models stop
        at once (u = 0: no point moves deeper, see the module docstring on stopping)."""
        return np.zeros(self.n)

    def barrier(self, s: FilterState, sample: FieldSample, hb: np.ndarray) -> np.ndarray:
        """The barrier the rows keep non-negative, from hb = d - r - δ (the same for
        first-order models; the double integrator subtracts its braking distance)."""
        return hb

    def alpha_cap(self, a_brake: float) -> float:
        """Largest first-order gain whose speed limit α h can be shed within h at deceleration
        ``a_brake`` (module docstring): 2 a / (largest point speed)."""
        return 2.0 * a_brake / self.max_point_speed()

    @abstractmethod
    def max_point_speed(self) -> float:
        """Largest speed of any barrier point within the input bounds (m/s): over one control
        period T the barrier can drop by at most this times T, which sizes the sampled-data margin."""

    @abstractmethod
    def integrate(self, s: FilterState, u: np.ndarray, dt: float, angular: np.ndarray | None = None) -> FilterState:
        """Exact solution of the dynamics over dt with the input held (zero-order hold)."""


class UnicycleLookahead(BarrierModel):
    """Unicycle with look-ahead point(s); input [v, ω]. Points are body-frame (x fwd, y left)."""

    name = "unicycle"

    def __init__(self, lookahead: float = 0.25, radius: float = 0.15, lambda_v: float = 1.0,
                 lambda_w: float = 0.5, v_max: float = 1.0, w_max: float = 2.0,
                 extra_points: list[tuple[float, float, float]] | None = None,
                 body: tuple[np.ndarray, np.ndarray] | None = None):
        """``body``: (offsets, radii) of the footprint's discs, after the look-ahead point (the
        paper's row, radius ``radius``) and the ``extra_points`` (radius ``radius``)."""
        pts = [(lookahead, 0.0, 0.0), *(extra_points or [])]
        radii = [radius] * len(pts)
        if body is not None:
            pts += [tuple(o) for o in np.asarray(body[0]).reshape(-1, 3)]
            radii += list(np.asarray(body[1]).reshape(-1))
        super().__init__(np.array(pts), np.array(radii), np.array([lambda_v, lambda_w]),
                         np.array([-v_max, -w_max]), np.array([v_max, w_max]))
        self.lookahead = lookahead

    def _rotation(self, s: FilterState) -> np.ndarray:
        return yaw_matrix(s.yaw)  # a ground robot: roll and pitch do not move its look-ahead point

    def _points_at(self, x: float, y: float, z: float, th: float) -> np.ndarray:
        c, sn = math.cos(th), math.sin(th)  # plain floats: a handful of points, called twice a step
        return np.array([(x + c * ox - sn * oy, y + sn * ox + c * oy, z + oz) for ox, oy, oz in self._offset_list])

    def points(self, s: FilterState) -> np.ndarray:
        p = s.position
        return self._points_at(float(p[0]), float(p[1]), float(p[2]), s.yaw)

    def predicted_points(self, s: FilterState, u: np.ndarray, dt: float, angular: np.ndarray | None) -> np.ndarray:
        x, y, th1 = self._arc(s, float(u[0]), float(u[1]), dt)
        return self._points_at(x, y, float(s.position[2]), th1)

    def _arc(self, s: FilterState, v: float, w: float, dt: float) -> tuple[float, float, float]:
        """Position and heading after dt at constant (v, ω): a straight line or a circular arc."""
        th = s.yaw
        th1 = th + w * dt
        if abs(w * dt) < 1e-9:
            dx, dy = v * dt * math.cos(th), v * dt * math.sin(th)
        else:
            dx = v / w * (math.sin(th1) - math.sin(th))
            dy = -v / w * (math.cos(th1) - math.cos(th))
        return float(s.position[0]) + dx, float(s.position[1]) + dy, th1

    def f(self, s: FilterState) -> np.ndarray:
        return np.zeros(3)

    def g(self, s: FilterState) -> np.ndarray:
        th = s.yaw
        return np.array([[math.cos(th), 0.0], [math.sin(th), 0.0], [0.0, 1.0]])

    def jacobians(self, s: FilterState) -> np.ndarray:
        """ṗ_i = J_i [v, ω] for every point, (m, 2, 2) (x, y rows)."""
        c, sn = math.cos(s.yaw), math.sin(s.yaw)
        ox, oy = self.offsets[:, 0], self.offsets[:, 1]
        j = np.empty((self.m, 2, 2))
        j[:, 0, 0], j[:, 1, 0] = c, sn
        j[:, 0, 1] = -(sn * ox + c * oy)
        j[:, 1, 1] = c * ox - sn * oy
        return j

    def rows(self, s: FilterState, sample: FieldSample, h: np.ndarray, gains: np.ndarray,
             angular: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = np.einsum("mk,mkj->mj", sample.gradient[:, :2], self.jacobians(s))
        return a, -gains[:, ALPHA] * h

    def reference(self, linear: np.ndarray, angular: np.ndarray, s: FilterState) -> np.ndarray:
        return np.array([linear[0], angular[2]], np.float64)

    def max_point_speed(self) -> float:
        # |J u|² = v² + ω²|o|² - 2 v ω o_y, largest at a corner of the box.
        v, w = self.hi
        o2 = (self.offsets[:, :2] ** 2).sum(axis=1)
        return float(np.sqrt(v * v + w * w * o2 + 2 * v * w * np.abs(self.offsets[:, 1])).max())

    def command(self, u: np.ndarray, angular: np.ndarray, s: FilterState) -> tuple[np.ndarray, np.ndarray]:
        return np.array([u[0], 0.0, 0.0]), np.array([0.0, 0.0, u[1]])

    def integrate(self, s: FilterState, u: np.ndarray, dt: float, angular: np.ndarray | None = None) -> FilterState:
        v, w = float(u[0]), float(u[1])
        x, y, th1 = self._arc(s, v, w, dt)
        pos = np.array([x, y, float(s.position[2])])
        return FilterState(pos, yaw_matrix(th1), np.array([v * math.cos(th1), v * math.sin(th1), 0.0]),
                           np.array([0.0, 0.0, w]))


class SingleIntegrator(BarrierModel):
    """ṗ = R u with u the body-frame linear velocity (2 or 3 components); ω passes through."""

    def __init__(self, dim: int = 2, radius: float | np.ndarray = 0.15, v_max: float = 1.0, vz_max: float = 0.5,
                 points: list[tuple[float, float, float]] | None = None, w_max: float = 2.0):
        if dim not in (2, 3):
            raise ValueError("dim must be 2 or 3")
        bound = np.array([v_max, v_max, vz_max])[:dim]
        super().__init__(np.array(points or [(0.0, 0.0, 0.0)]), radius, np.ones(dim), -bound, bound)
        self.dim, self.w_max = dim, w_max
        self.name = f"single{dim}d"  # type: ignore[misc]

    def _rotation(self, s: FilterState) -> np.ndarray:
        return yaw_matrix(s.yaw) if self.dim == 2 else s.rotation

    def _omega(self, angular: np.ndarray) -> np.ndarray:
        return np.array([0.0, 0.0, angular[2]]) if self.dim == 2 else np.asarray(angular, np.float64)

    def f(self, s: FilterState) -> np.ndarray:
        return np.zeros(self.dim)

    def g(self, s: FilterState) -> np.ndarray:
        return self._rotation(s)[: self.dim, : self.dim]

    def rows(self, s: FilterState, sample: FieldSample, h: np.ndarray, gains: np.ndarray,
             angular: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = self._rotation(s)
        a = sample.gradient @ r[:, : self.dim]
        if not self.offsets.any():
            return a, -gains[:, ALPHA] * h  # points at the centre do not move with the rotation
        spin = skew(self._omega(angular))  # ω × o for every body offset o
        drift = (self.offsets @ spin.T @ r.T * sample.gradient).sum(axis=1)
        return a, -gains[:, ALPHA] * h - drift

    def reference(self, linear: np.ndarray, angular: np.ndarray, s: FilterState) -> np.ndarray:
        return np.asarray(linear[: self.dim], np.float64).copy()

    def max_point_speed(self) -> float:
        # The passed-through rotation is not bounded by the filter: count w_max of the config.
        return float(np.linalg.norm(self.hi) + self.w_max * np.linalg.norm(self.offsets, axis=1).max())

    def command(self, u: np.ndarray, angular: np.ndarray, s: FilterState) -> tuple[np.ndarray, np.ndarray]:
        lin = np.zeros(3)
        lin[: self.dim] = u
        return lin, self._omega(angular)

    def integrate(self, s: FilterState, u: np.ndarray, dt: float, angular: np.ndarray | None = None) -> FilterState:
        w = self._omega(np.zeros(3) if angular is None else angular)
        r = self._rotation(s)
        ub = np.zeros(3)
        ub[: self.dim] = u
        pos = s.position + r @ so3_integral(w, dt) @ ub
        r1 = r @ so3_exp(w * dt)
        return FilterState(pos, r1, r1 @ ub, r1 @ w)


class DoubleIntegrator(BarrierModel):
    """ṗ = v, v̇ = u (world-frame acceleration), |u_i| ≤ a_max, with one of two barriers.

    Declared once: state x = (p, v), f(x) = (v, 0), g(x) = (0, I); h(x) = d(p) - r - δ, so
    ḣ = ∇dᵀv and ḧ = ∇dᵀu + vᵀ∇²d v. Both rows below are derived from these two derivatives.

    ``barrier="braking"`` (default): the braking-distance barrier. With s = -ḣ the approach
    speed along the gradient and a_b = ``brake_fraction`` · a_max the deceleration the barrier
    budgets for,

        h_b = h - φ(s),   φ(s) = (s² + s₀²) / (2 a_b)  for s ≥ s₀,   s₀ s / a_b  for s < s₀
        ḣ_b = ḣ - φ'(s) ṡ = ḣ + c (∇dᵀu + vᵀ∇²d v),   c = φ'(s) = max(s, s₀) / a_b

    φ is C¹ and φ(s) ≥ s²/(2a_b) for 0 ≤ s, so h_b ≥ 0 still means the robot can stop at a_b.
    The speed floor s₀ (``brake_speed_floor``) keeps the input's coefficient c ≥ s₀/a_b: with
    φ = s²/(2a_b) alone, c vanishes at rest and a robot at rest just inside its barrier (a
    sampled-data overshoot, in the corner between two obstacles where it has stopped) has no
    input that raises h_b at once — every such step was a relaxed QP. It costs at most
    s₀²/(2a_b) (5 mm for s₀ = 0.1 m/s, a_b = 1.05 m/s²) of clearance at s = s₀. For s < 0
    (moving away) φ < 0 credits the receding speed; h only grows while s < 0, and φ(0) = 0,
    so a state that keeps h_b ≥ 0 has h ≥ 0 whenever it approaches.

    and the row is the first-order CBF ḣ_b ≥ -κ h_b with κ = k₁, the slower root of the group's
    s² + α₁ s + α₂ = (s + k₁)(s + k₂): on the HOCBF's boundary h decays as e^{-k₁t} once the
    fast mode has died out, so the approach speed s ≤ κ h it allows near the obstacle is the one
    the paper's filter settles to, and the groups keep their ordering:

        (s₊/a_b) ∇dᵀu ≥ -κ h_b - ḣ - (s₊/a_b) vᵀ∇²d v.

    Far from the boundary the linear class-K function is needlessly tight: the row asks
    ḣ_b ≥ -κ h_b, and where the nearest obstacle changes (the ridge of the distance field
    between two obstacles or around a corner, vᵀ∇²d v ≈ -|∇²d| |v|² with |∇²d| up to
    20 m⁻¹ on 5 cm voxels) the approach speed s grows at -vᵀ∇²d v, so ḣ_b needs
    -s (1 + |vᵀ∇²d v| / a_b), several times κ h_b although braking (s²/(2a_b) of a few mm)
    is nowhere near. Any extended class-K function keeps {h_b ≥ 0} forward invariant, so the
    row uses

        α(h_b) = κ h_b (1 + h_b₊ / ℓ),      h_b₊ = max(h_b, 0),   ℓ = ``brake_rate_length``

    (continuous, strictly increasing, α(0) = 0; ℓ = ∞ is the linear κ h_b): the same κ h_b
    near the boundary — the settling speed and the groups' ordering are unchanged — and a
    rate that grows with the remaining clearance, so a state whose braking distance is far
    from the obstacle is not relaxed at a ridge. Per control period T, h_b can still drop by at
    most α(h_b) T < h_b while κ T (1 + h_b / ℓ) < 1 (κ = 1 s⁻¹, T = 50 ms, ℓ = 2 cm: every
    h_b < 0.38 m; beyond, the row allows more than h_b per period, but at |v| ≤ 0.5 m/s h_b
    cannot fall by more than a few cm in 50 ms).

    h_b ≥ 0 says that braking at a_b along the gradient stops the approach before d - r - δ
    reaches zero. Feasibility under the bounds: u = a_max ∇d/|∇d| (norm a_max, inside the box)
    gives ∇dᵀu ≥ a_max |∇d|, so at h_b = 0 the row holds whenever vᵀ∇²d v ≥ -(a_max|∇d| - a_b):
    the unused fraction of the deceleration absorbs the field's concave curvature (ridges between
    obstacles).

    ``barrier="hocbf"``: the paper's high-order CBF. With ψ₀ = h and the class-K pair (k₁, k₂),
    ψ₁ = ḣ + k₁ h and ψ̇₁ + k₂ ψ₁ ≥ 0 is ḧ + α₁ ḣ + α₂ h ≥ 0 with α₁ = k₁ + k₂, α₂ = k₁ k₂.
    Forward invariance needs real k's, i.e. α₁² ≥ 4 α₂ (otherwise h oscillates through zero); the
    filter's gain table enforces it. It ignores the bounds: from states with ψ₁ ≥ 0 it may need
    more than a_max. For ψ₁ ≥ 0 the row is exactly the paper's; see :meth:`_hocbf_rows` for ψ₁ < 0.

    Points are offsets from the centre in the world frame (the model has no attitude).
    In the node, the reference command's linear velocity (body frame) is a desired velocity
    tracked by u_ref = k_v (v_des - v); the filtered u becomes the velocity command v + u T
    one control period T ahead.
    """

    name = "double3d"
    needs_hessian = True

    def __init__(self, radius: float | np.ndarray = 0.15, a_max: float = 3.0, k_v: float = 2.0, dt: float = 0.02,
                 points: list[tuple[float, float, float]] | None = None, v_max: float = 1.0,
                 barrier: str = "braking", brake_fraction: float = 0.7, brake_rate_length: float = math.inf,
                 brake_speed_floor: float = 1e-3):
        super().__init__(np.array(points or [(0.0, 0.0, 0.0)]), radius, np.ones(3),
                         -np.full(3, a_max), np.full(3, a_max))
        if barrier not in ("braking", "hocbf") or not 0 < brake_fraction <= 1:
            raise ValueError("barrier is 'braking' or 'hocbf', brake_fraction in (0, 1]")
        self.k_v, self.dt, self.v_max = k_v, dt, v_max
        self.kind = barrier
        self.a_max = a_max
        self.a_brake = brake_fraction * a_max
        if not brake_rate_length > 0:
            raise ValueError("brake_rate_length must be positive (inf: the linear class-K function)")
        self.rate_length = brake_rate_length
        if not brake_speed_floor > 0:
            raise ValueError("brake_speed_floor must be positive")
        self.speed_floor = brake_speed_floor

    def braking_distance(self, approach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(φ(s), φ'(s)) of the braking barrier at the signed approach speeds s (class docstring)."""
        s0, ab = self.speed_floor, self.a_brake
        phi = np.where(approach >= s0, (approach * approach + s0 * s0) / (2 * ab), s0 * approach / ab)
        return phi, np.maximum(approach, s0) / ab

    def max_point_speed(self) -> float:
        # Velocity is a state here, not an input: v_max is the nominal speed the reference keeps.
        return self.v_max

    @staticmethod
    def roots(alpha1: float, alpha2: float) -> tuple[float, float]:
        """(k₁ ≤ k₂) with s² + α₁ s + α₂ = (s + k₁)(s + k₂), assuming α₁² ≥ 4 α₂. The safe set of
        the HOCBF is {h ≥ 0, ḣ + k₂ h ≥ 0}: a state must start there to be kept there."""
        disc = math.sqrt(max(alpha1 * alpha1 - 4 * alpha2, 0.0))
        return 0.5 * (alpha1 - disc), 0.5 * (alpha1 + disc)

    def points(self, s: FilterState) -> np.ndarray:
        return s.position + self.offsets

    def f(self, s: FilterState) -> np.ndarray:
        return np.concatenate([s.velocity, np.zeros(3)])

    def g(self, s: FilterState) -> np.ndarray:
        return np.vstack([np.zeros((3, 3)), np.eye(3)])

    def barrier(self, s: FilterState, sample: FieldSample, hb: np.ndarray) -> np.ndarray:
        if self.kind == "hocbf":
            return hb
        return hb - self.braking_distance(-(sample.gradient @ s.velocity))[0]

    def backup(self, s: FilterState, gradient: np.ndarray) -> np.ndarray:
        # Maximal acceleration along the gradient (norm a_max: inside the per-axis box).
        g = np.asarray(gradient, np.float64)
        n = float(np.linalg.norm(g))
        return self.a_max * g / n if n > 1e-9 else self.brake(s)

    def rows(self, s: FilterState, sample: FieldSample, h: np.ndarray, gains: np.ndarray,
             angular: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.kind == "hocbf":
            return self._hocbf_rows(s, sample, h, gains)
        v = s.velocity
        assert sample.hessian is not None
        curvature = np.einsum("i,mij,j->m", v, sample.hessian, v)
        hdot = sample.gradient @ v
        phi, c = self.braking_distance(-hdot)
        hbrake = h - phi
        a1, a2 = gains[:, ALPHA1], gains[:, ALPHA2]
        kappa = 0.5 * (a1 - np.sqrt(np.maximum(a1 * a1 - 4 * a2, 0.0)))
        rate = kappa * hbrake * (1.0 + np.maximum(hbrake, 0.0) / self.rate_length)  # α(h_b), class docstring
        return sample.gradient * c[:, None], -rate - hdot - c * curvature

    def _hocbf_rows(self, s: FilterState, sample: FieldSample, h: np.ndarray,
                    gains: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = s.velocity
        assert sample.hessian is not None
        curvature = np.einsum("i,mij,j->m", v, sample.hessian, v)
        hdot = sample.gradient @ v
        a1, a2 = gains[:, ALPHA1], gains[:, ALPHA2]
        disc = np.sqrt(np.maximum(a1 * a1 - 4 * a2, 0.0))
        k_slow, k_fast = 0.5 * (a1 - disc), 0.5 * (a1 + disc)
        psi1 = hdot + k_fast * h
        # Outside the HOCBF's safe set (ψ₁ < 0: approaching faster than k h allows, e.g. right after
        # the nearest obstacle switched to a group with smaller gains) the paper's row would let h
        # cross zero before ψ₁ recovers. Recovering ψ₁ at rate γ ≥ k_fast + 2|ψ₁|/h keeps
        # h(t) ≥ ½ h₀ e^{-k_fast t} (from ψ₁(t) ≥ ψ₁(0) e^{-γt} and ḣ = ψ₁ - k_fast h).
        gamma = np.where(psi1 < 0, np.maximum(k_slow, k_fast + 2 * np.abs(psi1) / np.maximum(h, 1e-3)), k_slow)
        b = -curvature - (k_fast + gamma) * hdot - gamma * k_fast * h
        return sample.gradient.copy(), b

    def reference(self, linear: np.ndarray, angular: np.ndarray, s: FilterState) -> np.ndarray:
        return self.k_v * (s.rotation @ np.asarray(linear, np.float64) - s.velocity)

    def command(self, u: np.ndarray, angular: np.ndarray, s: FilterState) -> tuple[np.ndarray, np.ndarray]:
        return s.rotation.T @ (s.velocity + u * self.dt), np.asarray(angular, np.float64).copy()

    def brake(self, s: FilterState) -> np.ndarray:
        # Straight against the velocity, scaled into the bounds (clipping per axis would turn it).
        a = -s.velocity / self.dt
        peak = float(np.max(np.abs(a) / self.hi))
        return a / peak if peak > 1.0 else a

    def integrate(self, s: FilterState, u: np.ndarray, dt: float, angular: np.ndarray | None = None) -> FilterState:
        return FilterState(s.position + s.velocity * dt + 0.5 * u * dt * dt, s.rotation, s.velocity + u * dt,
                           s.angular_velocity)
