"""Barrier models: the robot dynamics ẋ = f(x) + g(x) u, the barrier h(x) = d(p) - r at one or
more points p of the robot, and the affine CBF row (A u ≥ b) each point adds to the QP.

Each model is one description (:class:`~.model.ModelSpec`, declared by the constructors below:
body twist per unit input, pass-through rates, body points, box); :class:`BarrierModel` and the
compiled step (``compiled``) derive everything from it through the functions of ``model``, where
the rows are written once.

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
from dataclasses import dataclass

import numpy as np

from riskfield.protocol.platforms import LIMO

from ..fields import DistanceField, FieldSample
from . import model as mdl
from .model import ALPHA, ALPHA1, ALPHA2, MARGIN, ModelSpec
from .state import FilterState

__all__ = ["ALPHA", "ALPHA1", "ALPHA2", "MARGIN", "BarrierModel", "DoubleIntegrator", "SingleIntegrator",
           "UnicycleLookahead", "disc_cover"]

_NO_HESSIAN = np.zeros((1, 3, 3))
_STILL = np.zeros(3)  # the velocity of the field's obstacles (model.point_row's wobj)


def _f64(a: np.ndarray) -> np.ndarray:
    """C-contiguous float64: the one array type the model functions are compiled for."""
    return np.ascontiguousarray(a, np.float64)


def disc_cover(length: float, width: float, discs: int, capsule: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Discs on the medial axis (body x) whose union covers a length × width rectangle
    (or capsule) centred on the body origin: (offsets (k, 3), radii (k,)).

    The rectangle is cut into k equal slices of length ℓ = L/k; the disc at the centre of a slice
    with radius √((ℓ/2)² + (W/2)²) contains that slice (its farthest points are the slice's
    corners). A capsule (a W-wide rectangle of length L - W with half-disc ends) is covered the
    same way with the centres on its segment and the end discs' radius W/2 reaching its ends.
    For the LIMO's body (``protocol.platforms.LIMO``, k = 3) the discs overhang the sides by 1.2 cm.
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


class BarrierModel:
    """A robot model from its description (``spec``): body points, h, motion, CBF rows, inputs.

    Everything model-specific is data of the :class:`~.model.ModelSpec`; the methods pass it to
    the functions of ``model`` (the same ones the compiled step runs), so a new model or body
    point is one description.
    """

    def __init__(self, spec: ModelSpec):
        self.spec = spec
        self.name = spec.name
        self.needs_hessian = spec.order == 2
        self.offsets, self.radius, self.weights, self.lo, self.hi = (spec.offsets, spec.radii, spec.weights,
                                                                     spec.lo, spec.hi)
        self.di, self.df = spec.packed
        self.dl = spec.layout
        self.desc = (self.di, self.df, self.dl)  # the packed description as model's functions take it

    @property
    def n(self) -> int:
        """Number of inputs."""
        return self.spec.n

    @property
    def m(self) -> int:
        """Number of barrier points (one row each)."""
        return self.spec.m

    # -- points and motion ----------------------------------------------------------------------
    def rotation(self, s: FilterState) -> np.ndarray:
        """The rotation that carries the body points (the state's, its yaw, or the identity)."""
        out = np.empty((3, 3))
        mdl.attitude_rotation(self.di, _f64(s.rotation), out)
        return out

    def points(self, s: FilterState) -> np.ndarray:
        """World positions of the barrier points, (m, 3)."""
        pts = np.empty((self.m, 3))
        mdl.place_points(self.df, self.dl, _f64(s.position), self.rotation(s), pts, 0)
        return pts

    def _flow(self, s: FilterState, u: np.ndarray, dt: float, angular: np.ndarray | None):
        ang = np.zeros(3) if angular is None else _f64(angular)
        pos1, rot1, vel1, w1 = np.empty(3), np.empty((3, 3)), np.empty(3), np.empty(3)
        mdl.flow(self.desc, (_f64(s.position), _f64(s.rotation), _f64(s.velocity)), _f64(u), ang, float(dt),
                 (pos1, rot1, vel1, w1), (np.empty((3, 3)), np.empty((3, 3))))
        return pos1, rot1, vel1, w1

    def predicted_points(self, s: FilterState, u: np.ndarray, dt: float, angular: np.ndarray | None) -> np.ndarray:
        """The barrier points after dt with the input held (exact)."""
        return self.points(self.integrate(s, u, dt, angular))

    def integrate(self, s: FilterState, u: np.ndarray, dt: float, angular: np.ndarray | None = None) -> FilterState:
        """Exact solution of the dynamics over dt with the input held (zero-order hold)."""
        pos1, rot1, vel1, w1 = self._flow(s, u, dt, angular)
        if self.spec.order == 2:
            return FilterState(pos1, s.rotation, vel1, s.angular_velocity)
        return FilterState(pos1, rot1, vel1, w1)

    def point_jacobians(self, s: FilterState) -> np.ndarray:
        """ṗ_i = J_i u + (pass-through rotation) for every point, (m, 3, n), world frame (order 1):
        J_i = R (G_lin - [o_i]× G_ang)."""
        r, sp = self.rotation(s), self.spec
        arm = np.cross(self.offsets[:, None, :], sp.ang.T[None, :, :])  # o × (G_ang column) = [o]× G_ang
        return np.einsum("ab,mjb->maj", r, sp.lin.T[None] - arm)

    # -- barrier and rows -----------------------------------------------------------------------
    def h(self, s: FilterState, field: DistanceField) -> np.ndarray:
        """h_i = d(p_i) - r_i at every point (without the sampled-data margin)."""
        return field.query(self.points(s)).distance - self.radius

    def barrier(self, s: FilterState, sample: FieldSample, hb: np.ndarray,
                gains: np.ndarray | None = None) -> np.ndarray:
        """The barrier the rows keep non-negative, from hb = d - r - δ (the same for first-order
        models; the braking barrier subtracts its braking distance). ``gains`` (m, ≥ 3), the rows'
        [α, α₁, α₂]: the braking barrier's speed floor a_b / k₂ comes from them when none is
        configured (``model.speed_floor``)."""
        grad, vel = _f64(sample.gradient), _f64(s.velocity)
        g = np.zeros((len(hb), mdl.GAIN_COLUMNS))
        if gains is not None:
            g[:, : np.shape(gains)[-1]] = gains
        elif self.spec.barrier == "braking" and self.spec.speed_floor <= 0:
            raise ValueError("the braking barrier's speed floor comes from the rows' gains: pass them")
        return np.array([mdl.barrier_value(self.di, self.df, self.dl, float(hb[i]), grad[i], vel, _STILL, g[i])
                         for i in range(len(hb))])

    def rows(self, s: FilterState, sample: FieldSample, h: np.ndarray, gains: np.ndarray,
             angular: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """CBF rows A u ≥ b at the points (``model.point_row``): ``h`` (m,) barrier values,
        ``gains`` (m, ≥ 4), ``angular`` the reference's body rates; the field does not move."""
        m = len(h)
        a, b = np.empty((m, self.n)), np.empty(m)
        hess = _NO_HESSIAN if sample.hessian is None else _f64(sample.hessian)
        g = np.zeros((m, mdl.GAIN_COLUMNS))
        g[:, : np.asarray(gains).shape[1]] = gains
        mdl.point_rows(self.desc, (self.rotation(s), _f64(angular), _f64(s.velocity)),
                       _f64(sample.gradient), hess, _f64(h), g, _STILL, a, b)
        return a, b

    def braking_distance(self, approach: np.ndarray, gain: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(φ(s), φ'(s)) of the braking barrier at the signed approach speeds s (``DoubleIntegrator``);
        ``gain`` [α, α₁, α₂] sets the speed floor when none is configured."""
        sp = self.spec
        g = np.zeros(4)
        if gain is not None:
            g[: len(gain)] = gain
        elif sp.speed_floor <= 0:
            raise ValueError("the braking barrier's speed floor comes from the gains: pass them")
        s0 = mdl.speed_floor(mdl.DESC.view(self.df, self.dl, "brake"), g)
        out = [mdl.braking(float(x), s0, sp.a_brake) for x in np.ravel(approach)]
        shape = np.shape(approach)
        return np.array([o[0] for o in out]).reshape(shape), np.array([o[1] for o in out]).reshape(shape)

    # -- inputs ---------------------------------------------------------------------------------
    def reference(self, linear: np.ndarray, angular: np.ndarray, s: FilterState) -> np.ndarray:
        """The model input matching a body-frame velocity command: the components the input map
        selects (order 1), or k_v (v_des - v) towards it (order 2, world frame)."""
        sp = self.spec
        if sp.order == 2:
            return sp.k_v * (s.rotation @ np.asarray(linear, np.float64) - s.velocity)
        return sp.lin.T @ np.asarray(linear, np.float64) + sp.ang.T @ np.asarray(angular, np.float64)

    def command(self, u: np.ndarray, angular: np.ndarray, s: FilterState) -> tuple[np.ndarray, np.ndarray]:
        """Body-frame (linear, angular) velocity command of a model input."""
        sp = self.spec
        if sp.order == 2:
            return s.rotation.T @ (s.velocity + u * sp.dt), np.asarray(angular, np.float64).copy()
        return sp.lin @ u, sp.ang @ u + np.asarray(sp.passthrough) * np.asarray(angular, np.float64)

    def brake(self, s: FilterState) -> np.ndarray:
        """The input that stops the robot (zero velocity for velocity-controlled models)."""
        out = np.empty(self.n)
        mdl.brake_input(self.di, self.df, self.dl, _f64(s.velocity), self.spec.dt, out)
        return out

    def backup(self, s: FilterState, gradient: np.ndarray) -> np.ndarray:
        """The maximal-braking input along the field's gradient: what the slack-relaxed QP must do
        at least as well as, row by row (``model.backup_input``)."""
        out = np.empty(self.n)
        mdl.backup_input(self.di, self.df, self.dl, _f64(gradient), _f64(s.velocity), self.spec.dt, out)
        return out

    def alpha_cap(self, a_brake: float) -> float:
        """Largest first-order gain whose speed limit α h can be shed within h at deceleration
        ``a_brake`` (module docstring): 2 a / (largest point speed)."""
        return 2.0 * a_brake / self.max_point_speed()

    def max_point_speed(self) -> float:
        """Largest speed of any barrier point within the input bounds (m/s): over one control
        period T the barrier can drop by at most this times T, which sizes the sampled-data margin.
        Order 1: |G_lin u + (G_ang u) × o| is convex in u, so its largest value is at a corner of
        the box; the passed-through rates (not bounded by the filter) add w_max |o|. Order 2:
        velocity is a state, and the nominal speed the reference keeps bounds it."""
        sp = self.spec
        if sp.order == 2:
            return sp.point_speed
        corners = np.array(np.meshgrid(*[(lo, hi) for lo, hi in zip(sp.lo, sp.hi, strict=True)])).reshape(sp.n, -1).T
        v, w = corners @ sp.lin.T, corners @ sp.ang.T  # (corners, 3)
        speed = np.linalg.norm(v[:, None, :] + np.cross(w[:, None, :], self.offsets[None]), axis=2).max(axis=0)
        if any(sp.passthrough):
            speed = speed + sp.w_max * np.linalg.norm(self.offsets, axis=1)
        return float(speed.max())


# --------------------------------------------------------------------------- the models, declared once

_E = np.eye(3)


class UnicycleLookahead(BarrierModel):
    """Unicycle with look-ahead point(s); input [v, ω]: v along body x, ω about body z, nothing
    passed through. Points are body-frame (x fwd, y left)."""

    def __init__(self, lookahead: float = 0.25, radius: float = 0.15, lambda_v: float = 1.0,
                 lambda_w: float = 0.5, v_max: float = LIMO.max_linear, w_max: float = LIMO.max_angular,
                 extra_points: list[tuple[float, float, float]] | None = None,
                 body: tuple[np.ndarray, np.ndarray] | None = None):
        """``body``: (offsets, radii) of the footprint's discs, after the look-ahead point (the
        paper's row, radius ``radius``) and the ``extra_points`` (radius ``radius``)."""
        pts = [(lookahead, 0.0, 0.0), *(extra_points or [])]
        radii = [radius] * len(pts)
        if body is not None:
            pts += [tuple(o) for o in np.asarray(body[0]).reshape(-1, 3)]
            radii += list(np.asarray(body[1]).reshape(-1))
        super().__init__(ModelSpec(
            "unicycle", order=1, attitude="yaw", lin=[[1, 0], [0, 0], [0, 0]], ang=[[0, 0], [0, 0], [0, 1]],
            passthrough=(0.0, 0.0, 0.0), offsets=np.array(pts), radii=np.array(radii),
            weights=np.array([lambda_v, lambda_w]), lo=np.array([-v_max, -w_max]), hi=np.array([v_max, w_max])))
        self.lookahead = lookahead


class SingleIntegrator(BarrierModel):
    """ṗ = R u with u the body-frame linear velocity (2 or 3 components); the body turns at the
    reference's rates (its yaw rate in 2-D), which pass through."""

    def __init__(self, dim: int = 2, radius: float | np.ndarray = 0.15, v_max: float = 1.0, vz_max: float = 0.5,
                 points: list[tuple[float, float, float]] | None = None, w_max: float = 2.0):
        if dim not in (2, 3):
            raise ValueError("dim must be 2 or 3")
        bound = np.array([v_max, v_max, vz_max])[:dim]
        super().__init__(ModelSpec(
            f"single{dim}d", order=1, attitude="yaw" if dim == 2 else "full", lin=_E[:, :dim],
            ang=np.zeros((3, dim)), passthrough=(0.0, 0.0, 1.0) if dim == 2 else (1.0, 1.0, 1.0),
            offsets=np.array(points or [(0.0, 0.0, 0.0)]), radii=radius, weights=np.ones(dim), lo=-bound, hi=bound,
            w_max=w_max))
        self.dim, self.w_max = dim, w_max


@dataclass(frozen=True)
class Braking:
    """The double integrator's barrier (``DoubleIntegrator``): ``kind`` "braking" or "hocbf", the
    braking barrier's deceleration as a ``fraction`` of a_max, its class-K ``rate_length`` ℓ (inf:
    linear) and ``speed_floor`` s₀ (None: a_b / k₂ of each row's gains)."""

    kind: str = "braking"
    fraction: float = 0.7
    rate_length: float = math.inf
    speed_floor: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("braking", "hocbf") or not 0 < self.fraction <= 1:
            raise ValueError("barrier is 'braking' or 'hocbf', brake_fraction in (0, 1]")
        if not self.rate_length > 0:
            raise ValueError("brake_rate_length must be positive (inf: the linear class-K function)")
        if self.speed_floor is not None and not self.speed_floor > 0:
            raise ValueError("brake_speed_floor must be positive (None: a_b / k₂ of each row's gains)")


class DoubleIntegrator(BarrierModel):
    """ṗ = v, v̇ = u (world-frame acceleration), |u_i| ≤ a_max, with one of two barriers.

    Declared once: state x = (p, v), f(x) = (v, 0), g(x) = (0, I); h(x) = d(p) - r - δ, so
    ḣ = ∇dᵀv and ḧ = ∇dᵀu + vᵀ∇²d v. Both rows (``model.point_row``) are derived from these two derivatives.

    ``barrier="braking"`` (default): the braking-distance barrier. With s = -ḣ the approach
    speed along the gradient and a_b = ``brake_fraction`` · a_max the deceleration the barrier
    budgets for,

        h_b = h - φ(s),   φ(s) = (s² + s₀²) / (2 a_b)  for s ≥ s₀,   s₀ s / a_b  for s < s₀
        ḣ_b = ḣ - φ'(s) ṡ = ḣ + c (∇dᵀu + vᵀ∇²d v),   c = φ'(s) = max(s, s₀) / a_b

    φ is C¹ and φ(s) ≥ s²/(2a_b) for 0 ≤ s, so h_b ≥ 0 still means the robot can stop at a_b.
    The safe set is {h ≥ 0, h_b ≥ 0} (``model.barrier_value``): h falls only while s > 0, and
    then h ≥ φ(s) > 0.

    The speed floor s₀ = a_b/k₂ (``FilterConfig``'s default, ``brake_speed_floor=None``; k₂ the faster root of
    the row's s² + α₁ s + α₂, per risk group): below it φ(s) = s/k₂, h_b = h + ḣ/k₂ = ψ₁/k₂ and
    the row ḣ_b ≥ -k₁ h_b below is, times k₂, the paper's HOCBF ḧ + α₁ ḣ + α₂ h ≥ 0. Above s₀ the
    parabola keeps the braking distance within the bounds. At h_b = 0 the row still holds for
    u = a_max ∇d/|∇d| when |∇d| = 1 and vᵀ∇²d v ≥ 0 (c = max(s, s₀)/a_b: c a_max ≥ s because
    a_max ≥ a_b and s ≤ max(s, s₀)): from its safe set the rows stay feasible within the
    bounds, which eq. 14 as written (``hocbf``, whose safe set admits any speed) cannot promise.
    Outside the safe set the row recovers at the HOCBF's rate γ = (1 + 2|h_b|/max(h, 1 mm))/c
    (``model.point_row``: ψ₁ = h_b/c, k_fast = 1/c); with a fixed floor, at the constant rate κ.

    A fixed speed floor s₀ (``brake_speed_floor``) keeps the input's coefficient c ≥ s₀/a_b: with
    φ = s²/(2a_b) alone, c vanishes at rest and a robot at rest just inside its barrier (a
    sampled-data overshoot, in the corner between two obstacles where it has stopped) has no
    input that raises h_b at once, and every such step is a relaxed QP. It costs at most
    s₀²/(2a_b) (5 mm for s₀ = 0.1 m/s, a_b = 1.05 m/s²) of clearance at s = s₀. For s < 0
    (moving away) φ < 0 credits the receding speed; h only grows while s < 0, and φ(0) = 0,
    so a state that keeps h_b ≥ 0 has h ≥ 0 whenever it approaches.

    The row is the first-order CBF ḣ_b ≥ -κ h_b with κ = k₁, the slower root of the group's
    s² + α₁ s + α₂ = (s + k₁)(s + k₂): on the HOCBF's boundary h decays as e^{-k₁t} once the
    fast mode has died out, so the approach speed s ≤ κ h it allows near the obstacle is the one
    the paper's filter settles to, and the groups keep their ordering:

        (s₊/a_b) ∇dᵀu ≥ -κ h_b - ḣ - (s₊/a_b) vᵀ∇²d v.

    (The default is the linear α(h_b) = κ h_b. A steeper one, below, makes fewer relaxed steps at the
    distance field's ridges but brings the robot to the map's surface fast: with s₀ = 0.1 m/s and
    ℓ = 2 cm it rides the surface within millimetres, so with no extra margin every few
    millimetres the map reads long are a collision.)
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
    more than a_max. For ψ₁ ≥ 0 the row is exactly the paper's; see ``model.point_row`` for ψ₁ < 0.

    Points are offsets from the centre in the world frame (the model has no attitude).
    In the node, the reference command's linear velocity (body frame) is a desired velocity
    tracked by u_ref = k_v (v_des - v); the filtered u becomes the velocity command v + u T
    one control period T ahead.
    """

    def __init__(self, radius: float | np.ndarray = 0.15, a_max: float = 3.0, k_v: float = 2.0, dt: float = 0.02,
                 points: list[tuple[float, float, float]] | None = None, v_max: float = 1.0,
                 barrier: Braking = Braking()):
        super().__init__(ModelSpec(
            "double3d", order=2, attitude="none", lin=_E, ang=np.zeros((3, 3)), passthrough=(1.0, 1.0, 1.0),
            offsets=np.array(points or [(0.0, 0.0, 0.0)]), radii=radius, weights=np.ones(3),
            lo=-np.full(3, a_max), hi=np.full(3, a_max), barrier=barrier.kind, a_brake=barrier.fraction * a_max,
            speed_floor=barrier.speed_floor or 0.0, rate_length=barrier.rate_length, a_max=a_max, k_v=k_v, dt=dt,
            point_speed=v_max))
        self.k_v, self.dt, self.v_max, self.kind, self.a_max = k_v, dt, v_max, barrier.kind, a_max
        self.a_brake, self.rate_length, self.speed_floor = barrier.fraction * a_max, barrier.rate_length, \
            barrier.speed_floor

    @staticmethod
    def roots(alpha1: float, alpha2: float) -> tuple[float, float]:
        """(k₁ ≤ k₂) with s² + α₁ s + α₂ = (s + k₁)(s + k₂), assuming α₁² ≥ 4 α₂. The safe set of
        the HOCBF is {h ≥ 0, ḣ + k₂ h ≥ 0}: a state must start there to be kept there."""
        disc = math.sqrt(max(alpha1 * alpha1 - 4 * alpha2, 0.0))
        return 0.5 * (alpha1 - disc), 0.5 * (alpha1 + disc)
