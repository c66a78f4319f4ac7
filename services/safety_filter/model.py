"""One description per robot model, and everything the filter derives from it.

A model is declared once, as data (:class:`ModelSpec`): how its body moves under the input, its
body points (offsets and radii), its input box and QP weights. The compiled step (``compiled``)
and the model's Python methods (``barriers``: the supervisor's braking input and barrier, the
simulators) consume the description packed into two flat arrays (:meth:`ModelSpec.pack`, carved
by :data:`DESC`), and all call the functions below for the points, the motion over one period,
the barrier values and the CBF rows, so each formula is written here and nowhere else. The
functions are ``numba.njit`` (the compiled step inlines them; Python callers call them once).

The dynamics, as cbfpy declares them (``cbfpy/cbfs/cbf.py``: ``f``, ``g`` and ``h`` declared once,
the rows from the Lie derivatives L_f h and L_g h, there a JVP of h along f and along g's
columns). Here the state is the body pose and the input enters through the body twist:

* order 1 (velocity control: unicycle, single integrators): the body's linear and angular
  velocity in the body frame are ``v_b = G_lin u`` and ``ω_b = G_ang u + P ω_ref`` (P selects the
  reference's body rates that pass through: f's only part). A body point at offset o moves as
  ṗ = R (v_b + ω_b × o), so with the body-frame gradient g = Rᵀ∇d and the arm c = o × g,

      L_g h = gᵀ G_lin + cᵀ G_ang,     L_f h = cᵀ P ω_ref

  (∇dᵀ R (ω × o) = ωᵀ (o × Rᵀ∇d)). The look-ahead point of the unicycle is one more body point.
* order 2 (acceleration control: double integrator): p̈ = R G_lin u with no attitude (R = I),
  ṗ = v, so L_f h = ∇dᵀ v, L_f² h = vᵀ∇²d v, L_g L_f h = gᵀ G_lin.

Moving obstacles: each tracked object is its own barrier. The ESDF shows a moving object where
it was, and its nearest-obstacle distance hides an object behind a nearer wall, so the field's
rows stay static (the object's voxels are geometry like any other) and every tracked object on a
collision course (:func:`object_course`) adds two analytic rows (:func:`object_sample`): a
vertical cylinder of its radius at its centre predicted to the instant the command takes effect,
h(p, t) = |p - c - w t|_xy - R - r - δ - margin, and the capsule that cylinder sweeps along w in
``object_sweep_s`` (the robot stops short of a crossing person's path, and inside that path may
not go deeper); both move rigidly with the object, so ∂h/∂t = -∇h·w exactly, with w raised by
the track's speed uncertainty σ towards the robot (the worst velocity within σ). Order 1:
ḣ = L_f h + L_g h u - ∇d·w ≥ -α h; order 2: ḣ = ∇dᵀ(v - w) and ḧ keeps (v - w)ᵀ∇²d (v - w),
the relative velocity (:func:`point_row` takes the obstacle's velocity; 0 for the field).

Yielding. A row of a moving object, or of the field where its nearest obstacle is of a group that
yields (``YIELD``: people and animals by default), may slow and stop the robot but never push it:
its b is clipped to what the stopping input achieves (:func:`yield_clip`), and while such a row is
live the box is :func:`yield_box`, every input between zero and the reference's (the robot can
slow, stop and turn less, never reverse, speed up or steer on its own). Someone who walks into a
stopped robot leaves it stopped (the clip says so: ``yielding``). Static obstacles keep their
rows unclipped and the full box, recovery from inside a margin included.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from riskfield.protocol.kernels import Layout, view1, view2

from ..runtime.jit import jit

# How the body points turn with the robot (ModelSpec.attitude).
NO_ATTITUDE, YAW, FULL = 0, 1, 2
# The barrier condition (ModelSpec.barrier): order 1 is the first-order CBF; order 2 has two.
FIRST_ORDER, BRAKING, HOCBF = 0, 1, 2
BARRIERS = {"cbf": FIRST_ORDER, "braking": BRAKING, "hocbf": HOCBF}
ATTITUDES = {"none": NO_ATTITUDE, "yaw": YAW, "full": FULL}
# Columns of a gain table row (filter.GainTable): the gains, the group's inflation margin, and 1.0
# where the group yields (module docstring).
ALPHA, ALPHA1, ALPHA2, MARGIN, YIELD = 0, 1, 2, 3, 4
GAIN_COLUMNS = 5


class DescInts(IntEnum):
    """The integer part of a packed description."""

    ORDER = 0
    ATTITUDE = 1
    BARRIER = 2
    N = 3
    M = 4


#: The float part of a packed description: the input map (g), the pass-through rates (f), the
#: body points, the QP's weights and box, and the braking barrier's constants.
DESC = Layout("Desc", [("lin", (3, "n")), ("ang", (3, "n")), ("passthrough", (3,)), ("offsets", ("m", 3)),
                       ("radii", ("m",)), ("weights", ("n",)), ("lo", ("n",)), ("hi", ("n",)),
                       ("brake", (4,)), ("track", (1,))])
_D = DESC.slot
# The braking constants (DESC "brake"): a_b, the speed floor s₀ (0: a_b / k₂ of each row's gains,
# ``speed_floor``), the rate length ℓ, a_max.
A_BRAKE, SPEED_FLOOR, RATE_LENGTH, A_MAX = 0, 1, 2, 3
# The velocity tracking of order 2 (DESC "track"): k_v.
K_V = 0
# Columns of a moving-object row (``motion.object_table``): centre predicted to the instant the
# command takes effect, velocity, radius, the field's risk group id, speed uncertainty σ (m/s).
OBJ_X, OBJ_Y, OBJ_Z, OBJ_VX, OBJ_VY, OBJ_VZ, OBJ_RADIUS, OBJ_GROUP, OBJ_SIGMA = range(9)
OBJECT_COLUMNS = 9
# Times at which object_course samples the horizon (0, T/N, ..., T).
COURSE_SAMPLES = 12
# How far below what stopping achieves a yielding row's b is clipped (yield_clip).
YIELD_TOL = 1e-8


def _matrix(rows: object, n: int) -> np.ndarray:
    a = np.asarray(rows, np.float64).reshape(3, n)
    return a


@dataclass(frozen=True)
class ModelSpec:
    """A robot model, declared once (module docstring).

    ``lin``/``ang`` (3 × n): the body-frame linear and angular velocity per unit input (the
    linear acceleration, world frame, for ``order`` 2). ``passthrough`` (3): which components of
    the reference's body rates the robot keeps turning at (1) while the filter shapes u.
    ``offsets`` (m × 3, body frame; world frame without attitude) and ``radii`` (m): the barrier
    points, h_i = d(p + R o_i) - r_i. ``weights``, ``lo``, ``hi`` (n): the QP's weights and box
    (the box contains 0: braking). ``barrier``: ``cbf`` for order 1; ``braking`` or ``hocbf``
    for order 2 with the constants ``a_brake``, ``speed_floor`` (0: a_b / k₂ from each row's gains,
    :func:`speed_floor`), ``rate_length``, ``a_max``.
    ``k_v``, ``dt``: order 2 tracks a desired velocity with u = k_v (v_des - v) and commands the
    velocity v + u dt. ``point_speed``: order 2's nominal largest point speed (velocity is a
    state there); ``w_max`` bounds the passed-through rates for the sampled-data margin.
    """

    name: str
    order: int
    attitude: str
    lin: np.ndarray
    ang: np.ndarray
    passthrough: tuple[float, float, float]
    offsets: np.ndarray
    radii: np.ndarray
    weights: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    barrier: str = "cbf"
    a_brake: float = 1.0
    speed_floor: float = 1.0
    rate_length: float = math.inf
    a_max: float = 0.0
    k_v: float = 0.0
    dt: float = 0.02
    point_speed: float = 0.0
    w_max: float = 0.0
    packed: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = int(np.asarray(self.weights).reshape(-1).shape[0])
        offsets = np.asarray(self.offsets, np.float64).reshape(-1, 3)
        if offsets.shape[0] == 0:
            raise ValueError("a barrier model needs at least one point")
        radii = np.broadcast_to(np.asarray(self.radii, np.float64), (offsets.shape[0],)).copy()
        for k, v in (("lin", _matrix(self.lin, n)), ("ang", _matrix(self.ang, n)), ("offsets", offsets),
                     ("radii", radii), ("weights", np.asarray(self.weights, np.float64).reshape(n)),
                     ("lo", np.asarray(self.lo, np.float64).reshape(n)),
                     ("hi", np.asarray(self.hi, np.float64).reshape(n))):
            object.__setattr__(self, k, v)
        if not (np.all(self.weights > 0) and np.all(self.lo <= 0) and np.all(self.hi >= 0)):
            raise ValueError("weights must be positive and the bounds must contain zero (braking)")
        if self.order not in (1, 2) or self.attitude not in ATTITUDES:
            raise ValueError("order is 1 or 2, attitude 'none', 'yaw' or 'full'")
        if (self.order == 1) != (self.barrier == "cbf") or self.barrier not in BARRIERS:
            raise ValueError("order 1 has the barrier 'cbf', order 2 'braking' or 'hocbf'")
        if self.order == 2 and (self.attitude != "none" or self.ang.any() or self.n != 3
                                or not np.array_equal(self.lin, np.eye(3))):
            raise ValueError("an order-2 model has no attitude and a world-frame acceleration input (lin = I)")
        object.__setattr__(self, "packed", self.pack())

    @property
    def n(self) -> int:
        return self.weights.shape[0]

    @property
    def m(self) -> int:
        return self.offsets.shape[0]

    @property
    def layout(self) -> np.ndarray:
        """The :data:`DESC` table of this model's dimensions."""
        return DESC.table(n=self.n, m=self.m)

    def pack(self) -> tuple[np.ndarray, np.ndarray]:
        """(ints (:class:`DescInts`), floats (:data:`DESC`)): the description as the functions
        below read it."""
        ints = np.zeros(len(DescInts), np.int64)
        ints[DescInts.ORDER], ints[DescInts.ATTITUDE] = self.order, ATTITUDES[self.attitude]
        ints[DescInts.BARRIER], ints[DescInts.N], ints[DescInts.M] = BARRIERS[self.barrier], self.n, self.m
        table = self.layout
        floats = np.zeros(Layout.size(table))
        brake = np.array([self.a_brake, self.speed_floor, self.rate_length, self.a_max], np.float64)
        for name, value in (("lin", self.lin), ("ang", self.ang), ("passthrough", self.passthrough),
                            ("offsets", self.offsets), ("radii", self.radii), ("weights", self.weights),
                            ("lo", self.lo), ("hi", self.hi), ("brake", brake), ("track", (self.k_v,))):
            DESC.view(floats, table, name)[...] = value
        return ints, floats


# --------------------------------------------------------------------------- SO(3) (state.py's series)


@jit
def _series(x, y, z, t, c1, c2, out):
    """t·I + c1·[w]× + c2·[w]×² (state._series)."""
    xx, yy, zz, xy, xz, yz = x * x, y * y, z * z, x * y, x * z, y * z
    out[0, 0] = t - c2 * (yy + zz)
    out[0, 1] = -c1 * z + c2 * xy
    out[0, 2] = c1 * y + c2 * xz
    out[1, 0] = c1 * z + c2 * xy
    out[1, 1] = t - c2 * (xx + zz)
    out[1, 2] = -c1 * x + c2 * yz
    out[2, 0] = -c1 * y + c2 * xz
    out[2, 1] = c1 * x + c2 * yz
    out[2, 2] = t - c2 * (xx + yy)


@jit
def so3_exp(x, y, z, out):
    th = math.sqrt(x * x + y * y + z * z)
    if th < 1e-9:
        _series(x, y, z, 1.0, 1.0, 0.5, out)
    else:
        _series(x, y, z, 1.0, math.sin(th) / th, (1 - math.cos(th)) / th**2, out)


@jit
def so3_integral(x, y, z, t, out):
    th = math.sqrt(x * x + y * y + z * z)
    if abs(th * t) < 1e-6:
        _series(x, y, z, t, 0.5 * t * t, t**3 / 6.0, out)
    else:
        _series(x, y, z, t, (1 - math.cos(th * t)) / th**2, (th * t - math.sin(th * t)) / th**3, out)


@jit
def yaw_rotation(yaw, out):
    c, s = math.cos(yaw), math.sin(yaw)
    out[:, :] = 0.0
    out[0, 0], out[0, 1], out[1, 0], out[1, 1], out[2, 2] = c, -s, s, c, 1.0


# --------------------------------------------------------------------------- points and motion


@jit
def attitude_rotation(di, rot, out):
    """The rotation that carries the body points: the state's, its yaw, or none (identity)."""
    att = di[DescInts.ATTITUDE]
    if att == FULL:
        out[:, :] = rot
    elif att == YAW:
        yaw_rotation(math.atan2(rot[1, 0], rot[0, 0]), out)
    else:
        out[:, :] = 0.0
        out[0, 0], out[1, 1], out[2, 2] = 1.0, 1.0, 1.0


@jit
def place_points(df, dl, pos, rot_att, pts, row0):
    """pts[row0 + i] = p + R o_i for every body point."""
    offsets = view2(df, dl, _D.offsets)
    for i in range(offsets.shape[0]):
        for a in range(3):
            pts[row0 + i, a] = pos[a] + rot_att[a, 0] * offsets[i, 0] + rot_att[a, 1] * offsets[i, 1] \
                + rot_att[a, 2] * offsets[i, 2]


@jit
def flow(desc, start, u, ang, dt, end, scratch):
    """The exact motion over dt with u held (zero-order hold) from ``start`` = (pos, rot, vel), the
    pose and world velocity, into ``end`` = (pos1, rot1, vel1, w1): the pose (rot1 the attitude
    rotation for order 1), world velocity and angular velocity; ``scratch`` two 3×3 arrays.
    ``desc`` is the packed description (di, df, dl) (:meth:`ModelSpec.pack`). Order 1: the body
    twist (v_b, ω_b) is constant, p₁ = p + R ∫₀ᵗexp(s[ω_b]×)ds v_b, R₁ = R exp(t[ω_b]×) (a straight
    line or an arc for the unicycle); order 2: p₁ = p + v t + ½ a t²."""
    di, df, dl = desc
    pos, rot, vel = start
    pos1, rot1, vel1, w1 = end
    s1, s2 = scratch
    lin, ang_g = view2(df, dl, _D.lin), view2(df, dl, _D.ang)
    pas = view1(df, dl, _D.passthrough)
    n = di[DescInts.N]
    if di[DescInts.ORDER] == 2:
        for a in range(3):
            acc = 0.0
            for j in range(n):
                acc += lin[a, j] * u[j]
            pos1[a] = pos[a] + vel[a] * dt + 0.5 * acc * dt * dt
            vel1[a] = vel[a] + acc * dt
            w1[a] = ang[a]
        rot1[:, :] = rot
        return
    attitude_rotation(di, rot, s1)
    # The body twist in w1 (ω_b) and vel1 (v_b) until the end, where they turn into world vectors.
    for a in range(3):
        v, w = 0.0, pas[a] * ang[a]
        for j in range(n):
            v += lin[a, j] * u[j]
            w += ang_g[a, j] * u[j]
        vel1[a], w1[a] = v, w
    so3_integral(w1[0], w1[1], w1[2], dt, s2)
    for a in range(3):
        d = 0.0
        for b in range(3):
            rs = 0.0
            for c in range(3):
                rs += s1[a, c] * s2[c, b]
            d += rs * vel1[b]
        pos1[a] = pos[a] + d
    so3_exp(w1[0] * dt, w1[1] * dt, w1[2] * dt, s2)
    for a in range(3):
        for b in range(3):
            s = 0.0
            for c in range(3):
                s += s1[a, c] * s2[c, b]
            rot1[a, b] = s
    if di[DescInts.ATTITUDE] == YAW:
        yaw_rotation(math.atan2(rot1[1, 0], rot1[0, 0]), rot1)
    v0, v1, v2, w0, w1_, w2 = vel1[0], vel1[1], vel1[2], w1[0], w1[1], w1[2]
    for a in range(3):
        vel1[a] = rot1[a, 0] * v0 + rot1[a, 1] * v1 + rot1[a, 2] * v2
        w1[a] = rot1[a, 0] * w0 + rot1[a, 1] * w1_ + rot1[a, 2] * w2


# --------------------------------------------------------------------------- barriers and rows


@jit
def braking(approach, s0, a_brake):
    """(φ(s), φ'(s)) of the braking barrier at the approach speed s (``barriers.DoubleIntegrator``)."""
    if approach >= s0:
        phi = (approach * approach + s0 * s0) / (2 * a_brake)
    else:
        phi = s0 * approach / a_brake
    return phi, max(approach, s0) / a_brake


@jit
def speed_floor(brake, gain):
    """The braking barrier's speed floor s₀ for a row with gains [α, α₁, α₂, ...]: the configured
    one, or (configured 0) a_b / k₂ with k₂ the faster root of s² + α₁ s + α₂. Below s₀ the
    braking distance is φ(s) = s / k₂ and h_b = h + ḣ / k₂ = ψ₁ / k₂: the row ḣ_b ≥ -k₁ h_b is then
    the paper's HOCBF ḧ + α₁ ḣ + α₂ h ≥ 0 (``barriers.DoubleIntegrator``)."""
    if brake[SPEED_FLOOR] > 0.0:
        return brake[SPEED_FLOOR]
    a1, a2 = gain[ALPHA1], gain[ALPHA2]
    k_fast = 0.5 * (a1 + math.sqrt(max(a1 * a1 - 4 * a2, 0.0)))
    return brake[A_BRAKE] / max(k_fast, 1e-9)


@jit
def barrier_value(di, df, dl, hb, grad, vel, wobj, gain):
    """The barrier whose non-negativity is the safe set at one point, from hb = d - r - δ: hb itself,
    or for the braking barrier min(hb, h_b), h_b = hb - φ(s) with s the approach speed relative to
    the obstacle (velocity ``wobj``; 0 for the field) and ``gain`` the row's gains, which set the
    speed floor. The rows keep h_b ≥ 0; a receding robot (s < 0) is credited φ(s) < 0, so h_b ≥ 0
    alone would call a robot inside an obstacle that backs out safe. With hb ≥ 0 as well it is: h
    falls only while s > 0, and then hb ≥ φ(s) > 0 (``barriers.DoubleIntegrator``)."""
    if di[DescInts.BARRIER] != BRAKING:
        return hb
    brake = view1(df, dl, _D.brake)
    hdot = grad[0] * (vel[0] - wobj[0]) + grad[1] * (vel[1] - wobj[1]) + grad[2] * (vel[2] - wobj[2])
    return min(hb, hb - braking(-hdot, speed_floor(brake, gain), brake[A_BRAKE])[0])


@jit
def barriers(desc, dist, grad, vel, gains, delta, margins, hb, wobj):
    """hb_i = d_i - r_i - δ (- the group's margin) at the body points, into hb; returns the
    critical point (smallest barrier value). ``wobj`` is a zero vector: the field does not move."""
    di, df, dl = desc
    radii = view1(df, dl, _D.radii)
    kbest, best = 0, math.inf
    for i in range(radii.shape[0]):
        hb[i] = dist[i] - radii[i] - delta
        if margins:
            hb[i] = hb[i] - gains[i, MARGIN]
        val = barrier_value(di, df, dl, hb[i], grad[i], vel, wobj, gains[i])
        if val < best or i == 0:
            kbest, best = i, val
    return kbest


@jit
def point_row(desc, motion, i, grad, hess, hb, gain, wobj, a_row):
    """The CBF row a·u ≥ b of body point i (module docstring) with the field sample (grad, hess)
    and gains [α, α₁, α₂, margin, yield] of its row, the barrier hb = d - r - δ of point i and the
    velocity ``wobj`` of the obstacle (0 for the field; an object's for :func:`object_sample`):
    writes a into a_row, returns b. ``motion`` = (rot, ang, vel): the attitude rotation, the
    reference's body rates and the world velocity. The only place the rows are written down."""
    di, df, dl = desc
    rot, ang, vel = motion
    lin, ang_g = view2(df, dl, _D.lin), view2(df, dl, _D.ang)
    o, pas = view2(df, dl, _D.offsets)[i], view1(df, dl, _D.passthrough)
    gx = rot[0, 0] * grad[0] + rot[1, 0] * grad[1] + rot[2, 0] * grad[2]  # g = Rᵀ∇d
    gy = rot[0, 1] * grad[0] + rot[1, 1] * grad[1] + rot[2, 1] * grad[2]
    gz = rot[0, 2] * grad[0] + rot[1, 2] * grad[1] + rot[2, 2] * grad[2]
    cx, cy, cz = o[1] * gz - o[2] * gy, o[2] * gx - o[0] * gz, o[0] * gy - o[1] * gx  # c = o × g
    for j in range(di[DescInts.N]):  # L_g h (order 1), L_g L_f h (order 2)
        a_row[j] = gx * lin[0, j] + gy * lin[1, j] + gz * lin[2, j] + cx * ang_g[0, j] + cy * ang_g[1, j] \
            + cz * ang_g[2, j]
    if di[DescInts.ORDER] == 1:
        lfh = cx * pas[0] * ang[0] + cy * pas[1] * ang[1] + cz * pas[2] * ang[2]
        dhdt = -(grad[0] * wobj[0] + grad[1] * wobj[1] + grad[2] * wobj[2])
        return -gain[ALPHA] * hb - (lfh + dhdt)  # ḣ = L_f h + L_g h u + ∂h/∂t ≥ -α h
    # Order 2 in the obstacle's frame: h(p - w t) has ḣ = ∇dᵀ(v - w), ḧ = ∇dᵀu + (v - w)ᵀ∇²d (v - w).
    r0, r1, r2 = vel[0] - wobj[0], vel[1] - wobj[1], vel[2] - wobj[2]
    curv = 0.0
    for a in range(3):
        ra = r0 if a == 0 else (r1 if a == 1 else r2)
        curv += ra * (hess[a, 0] * r0 + hess[a, 1] * r1 + hess[a, 2] * r2)
    hdot = grad[0] * r0 + grad[1] * r1 + grad[2] * r2
    a1, a2 = gain[ALPHA1], gain[ALPHA2]
    disc = math.sqrt(max(a1 * a1 - 4 * a2, 0.0))
    if di[DescInts.BARRIER] == BRAKING:
        brake = view1(df, dl, _D.brake)
        phi, cc = braking(-hdot, speed_floor(brake, gain), brake[A_BRAKE])
        hbrake = hb - phi
        kappa = 0.5 * (a1 - disc)
        rate = kappa * hbrake * (1.0 + max(hbrake, 0.0) / brake[RATE_LENGTH])  # α(h_b), DoubleIntegrator
        if hbrake < 0.0 and brake[SPEED_FLOOR] <= 0.0:
            # Outside the safe set (too fast for the clearance: a ridge crossed, the nearest obstacle
            # changed, a point cloud's nearest point switched) with the speed floor a_b/k₂, where
            # the barrier is the HOCBF: its recovery below with ψ₁ = h_b / c, k_fast = 1 / c, so h
            # stays positive instead of h_b creeping back at κ while the robot slides on into the
            # obstacle. A fixed floor keeps κ: the braking barrier with a constant recovery rate.
            rate = max(kappa, (1.0 + 2 * abs(hbrake) / max(hb, 1e-3)) / cc) * hbrake
        for j in range(di[DescInts.N]):
            a_row[j] = a_row[j] * cc
        return -rate - hdot - cc * curv
    # The paper's HOCBF. Outside its safe set (ψ₁ < 0: approaching faster than k h allows, e.g. right
    # after the nearest obstacle switched to a group with smaller gains) the paper's row would let h
    # cross zero before ψ₁ recovers. Recovering ψ₁ at rate γ ≥ k_fast + 2|ψ₁|/h keeps
    # h(t) ≥ ½ h₀ e^{-k_fast t} (from ψ₁(t) ≥ ψ₁(0) e^{-γt} and ḣ = ψ₁ - k_fast h).
    k_slow, k_fast = 0.5 * (a1 - disc), 0.5 * (a1 + disc)
    psi1 = hdot + k_fast * hb
    gamma = max(k_slow, k_fast + 2 * abs(psi1) / max(hb, 1e-3)) if psi1 < 0 else k_slow
    return -curv - (k_fast + gamma) * hdot - gamma * k_fast * hb


@jit
def point_rows(desc, motion, grad, hess, hb, gains, wobj, a, b):
    """Rows of every body point i with the field sample i (grad, hess, gains row i); the field
    does not move (``wobj`` a zero vector)."""
    for i in range(hb.shape[0]):
        b[i] = point_row(desc, motion, i, grad[i], hess[min(i, hess.shape[0] - 1)], hb[i], gains[i], wobj, a[i])


# --------------------------------------------------------------------------- moving objects


@jit
def _stopping(speed, a_stop, t):
    """Distance travelled in t by a body braking from ``speed`` at ``a_stop`` to rest."""
    if a_stop <= 0.0:
        return 0.0
    t_stop = speed / a_stop
    if t >= t_stop:
        return 0.5 * speed * t_stop
    return speed * t - 0.5 * a_stop * t * t


@jit
def reference_velocity(di, df, dl, rot_att, vel, u, out):
    """The world velocity the reference asks of the body origin: R G_lin u (order 1), or the
    velocity order 2's input u = k_v (v_des - v) tracks, v_des = v + u / k_v."""
    if di[DescInts.ORDER] == 2:
        kv = view1(df, dl, _D.track)[K_V]
        for a in range(3):
            out[a] = vel[a] + u[a] / kv
        return
    lin = view2(df, dl, _D.lin)
    for a in range(3):
        vb = 0.0
        for j in range(di[DescInts.N]):
            vb += lin[a, j] * u[j]
        out[a] = vb
    x, y, z = out[0], out[1], out[2]
    for a in range(3):
        out[a] = rot_att[a, 0] * x + rot_att[a, 1] * y + rot_att[a, 2] * z


@jit
def object_course(desc, pts, v_ref, vel, obj, margin, delta, horizon, a_stop):
    """When (s) a moving object first comes inside the margin of the robot's body within the
    horizon, or inf: whether it is on a collision course. Two futures of the body count: moving
    on at the reference's velocity ``v_ref`` (world), and braking at ``a_stop`` from its
    velocity ``vel`` to rest (the stopping footprint). The object moves on at its velocity, its
    position uncertain by σ t (σ: OBJ_SIGMA); the margin is the group's inflation plus δ. Someone
    walking past beside the robot or crossing behind it never comes inside: no row, no slowing."""
    df, dl = desc[1], desc[2]
    speed = math.sqrt(vel[0] * vel[0] + vel[1] * vel[1])
    ux, uy = (vel[0] / speed, vel[1] / speed) if speed > 1e-9 else (0.0, 0.0)
    for k in range(COURSE_SAMPLES + 1):
        t = horizon * k / COURSE_SAMPLES
        grow = margin + delta + obj[OBJ_SIGMA] * t
        s = _stopping(speed, a_stop, t)
        for f in range(2):
            dx, dy = (v_ref[0] * t, v_ref[1] * t) if f == 0 else (ux * s, uy * s)
            if object_gap(df, dl, pts, dx, dy, obj, t) <= grow:
                return t
    return math.inf


@jit
def object_gap(df, dl, pts, dx, dy, obj, t):
    """The horizontal gap between the body, moved by (dx, dy), and a moving object's cylinder
    after t s at its velocity: the smallest over the body's discs (< 0: they overlap)."""
    radii = view1(df, dl, _D.radii)
    ox, oy = obj[OBJ_X] + obj[OBJ_VX] * t, obj[OBJ_Y] + obj[OBJ_VY] * t
    best = math.inf
    for i in range(radii.shape[0]):
        ex, ey = pts[i, 0] + dx - ox, pts[i, 1] + dy - oy
        best = min(best, math.sqrt(ex * ex + ey * ey) - radii[i])
    return best - obj[OBJ_RADIUS]


@jit
def object_sample(desc, pts, obj, gain, delta, sweep, grad, hess, wobj):
    """The analytic field of one moving object at the body point nearest it: the capsule its
    cylinder sweeps from its predicted centre c along its velocity w for ``sweep`` seconds
    (radius R, inflated by its group's margin), so the robot keeps out of where the object is
    about to be, not only of where it is (someone crossing the lane diagonally is given the lane
    ahead of them). The capsule moves rigidly with w. Writes the horizontal gradient n, the
    Hessian of the horizontal distance ((I - n nᵀ)/ρ off the ends' caps, 0 along the side) and
    the velocity the row uses, w + σ n (the worst velocity within the track's uncertainty:
    towards the point); returns (the body point, hb = ρ - R - r - δ - margin)."""
    df, dl = desc[1], desc[2]
    radii = view1(df, dl, _D.radii)
    cx, cy, wx, wy = obj[OBJ_X], obj[OBJ_Y], obj[OBJ_VX] * sweep, obj[OBJ_VY] * sweep
    ww = wx * wx + wy * wy
    kbest, best, nx, ny, rho_b, side = 0, math.inf, 1.0, 0.0, 1.0, False
    for i in range(radii.shape[0]):
        s = 0.0
        if ww > 1e-12:
            s = min(max(((pts[i, 0] - cx) * wx + (pts[i, 1] - cy) * wy) / ww, 0.0), 1.0)
        dx, dy = pts[i, 0] - cx - s * wx, pts[i, 1] - cy - s * wy
        rho = math.sqrt(dx * dx + dy * dy)
        hb = rho - obj[OBJ_RADIUS] - radii[i] - delta - gain[MARGIN]
        if hb < best:
            kbest, best, rho_b, side = i, hb, rho, 0.0 < s < 1.0
            nx, ny = (dx / rho, dy / rho) if rho > 1e-9 else (1.0, 0.0)
    grad[0], grad[1], grad[2] = nx, ny, 0.0
    hess[:, :] = 0.0
    if not side:
        inv = 1.0 / max(rho_b, 1e-3)
        hess[0, 0], hess[0, 1], hess[1, 0], hess[1, 1] = (1 - nx * nx) * inv, -nx * ny * inv, -nx * ny * inv, \
            (1 - ny * ny) * inv
    sig = obj[OBJ_SIGMA]
    wobj[0], wobj[1], wobj[2] = obj[OBJ_VX] + sig * nx, obj[OBJ_VY] + sig * ny, obj[OBJ_VZ]
    return kbest, best


@jit
def yield_clip(di, a_row, b, u_stop):
    """A yielding row's b, clipped to what the stopping input achieves (module docstring), less
    ``YIELD_TOL``: the yield box has the stopping input at a corner, where an exact b would leave
    the QP feasible at that one point, infeasible by rounding. Returns (b', whether stopping alone
    does not keep this barrier). Velocity-controlled models only (order 1, where stopping is the
    zero input inside every box): an order-2 robot keeps its rows, braking and backing off along
    the gradient when a row asks for it (a drone evades)."""
    if di[DescInts.ORDER] != 1:
        return b, False
    au = 0.0
    for j in range(di[DescInts.N]):
        au += a_row[j] * u_stop[j]
    cap = au - YIELD_TOL * (1.0 + abs(au))
    if b > cap:
        return cap, b > au + YIELD_TOL * (1.0 + abs(au))
    return b, False


@jit
def yield_box(di, df, dl, u_ref, lo, hi):
    """The box while a yielding row is live: each input between zero and the reference's, so the
    robot can slow, stop and turn less, never reverse, speed up or steer on its own. Returns
    whether it applies: order 2 keeps its own box (:func:`yield_clip`)."""
    if di[DescInts.ORDER] != 1:
        return False
    lo0, hi0 = view1(df, dl, _D.lo), view1(df, dl, _D.hi)
    for j in range(di[DescInts.N]):
        r = min(max(u_ref[j], lo0[j]), hi0[j])
        lo[j], hi[j] = min(r, 0.0), max(r, 0.0)
    return True


@jit
def brake_input(di, df, dl, vel, dt, out):
    """The input that stops the robot: zero velocity (order 1), or straight against the velocity
    scaled into the box (order 2: clipping per axis would turn it)."""
    n = di[DescInts.N]
    for j in range(n):
        out[j] = 0.0
    if di[DescInts.ORDER] == 1:
        return
    hi = view1(df, dl, _D.hi)
    peak = 0.0
    for j in range(n):
        peak = max(peak, abs(-vel[j] / dt) / hi[j])
    for j in range(n):
        out[j] = -vel[j] / dt / peak if peak > 1.0 else -vel[j] / dt


@jit
def backup_input(di, df, dl, grad, vel, dt, out):
    """The maximal braking along the gradient of one row: order 2 accelerates at a_max along ∇d
    (norm a_max: inside the per-axis box); order 1 stops at once (u = 0: no point moves deeper)."""
    n = di[DescInts.N]
    if di[DescInts.ORDER] == 1:
        for j in range(n):
            out[j] = 0.0
        return
    gn = math.sqrt(grad[0] ** 2 + grad[1] ** 2 + grad[2] ** 2)
    if gn > 1e-9:
        a_max = view1(df, dl, _D.brake)[A_MAX]
        for j in range(n):
            out[j] = a_max * grad[j] / gn
    else:
        brake_input(di, df, dl, vel, dt, out)
