"""One description per robot model, and everything the filter derives from it, for both backends.

A model is declared once, as data (:class:`ModelSpec`): how its body moves under the input, its
body points (offsets and radii), its input box and QP weights. The numpy path (``barriers``,
``filter``) and the compiled step (``compiled``) both consume the description packed into two
flat arrays (:meth:`ModelSpec.pack`, carved by :data:`DESC`), and both call the functions below
for the points, the motion over one period, the barrier values and the CBF rows, so each formula
is written here and nowhere else. The functions are ``numba.njit`` where numba is installed (the
compiled step inlines them; the numpy path calls them once per step) and plain Python otherwise.

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

Moving obstacles. When the obstacle nearest a barrier point moves, the field moves with it:
h(p, t) = d(p - w t) - r, so ∂h/∂t = -∇d·w. Only the component towards the point counts (an
obstacle moving away must not loosen the barrier below the static one), the *closing speed*
σ = max(∇d·w, 0) ≥ 0 (:func:`closing_speeds`), and ∂h/∂t = -σ enters every row:
order 1: ḣ = L_f h + L_g h u - σ ≥ -α h; order 2: ḣ = ∇dᵀv - σ, and ḧ keeps vᵀ∇²d v (with
w = σ ∇d the cross terms vanish: ∇²d ∇d = 0 for a distance field). The map shows the obstacle
where it was at the map's stamp; by now it has come σ·age closer, so the barrier is lowered by
that much (:func:`barriers`). σ = 0 everywhere gives the static rows bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from ..fields.compiled import Layout, jit, view1, view2

# How the body points turn with the robot (ModelSpec.attitude).
NO_ATTITUDE, YAW, FULL = 0, 1, 2
# The barrier condition (ModelSpec.barrier): order 1 is the first-order CBF; order 2 has two.
FIRST_ORDER, BRAKING, HOCBF = 0, 1, 2
BARRIERS = {"cbf": FIRST_ORDER, "braking": BRAKING, "hocbf": HOCBF}
ATTITUDES = {"none": NO_ATTITUDE, "yaw": YAW, "full": FULL}
# Columns of a gain table row (filter.GainTable).
ALPHA, ALPHA1, ALPHA2, MARGIN = 0, 1, 2, 3


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
                       ("brake", (4,))])
_D = DESC.slot
# The braking constants (DESC "brake"): a_b, the speed floor s₀ (0: a_b / k₂ of each row's gains,
# ``speed_floor``), the rate length ℓ, a_max.
A_BRAKE, SPEED_FLOOR, RATE_LENGTH, A_MAX = 0, 1, 2, 3
# Columns of a moving-object row (closing_speeds): centre at the map's stamp, velocity, radius,
# the field's risk group id.
OBJ_X, OBJ_Y, OBJ_Z, OBJ_VX, OBJ_VY, OBJ_VZ, OBJ_RADIUS, OBJ_GROUP = range(8)
OBJECT_COLUMNS = 8


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
                            ("lo", self.lo), ("hi", self.hi), ("brake", brake)):
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
def flow(di, df, dl, pos, rot, vel, u, ang, dt, pos1, rot1, vel1, w1, s1, s2):
    """The exact motion over dt with u held (zero-order hold) from the pose (pos, rot) and velocity
    vel: pose (pos1, rot1 — the attitude rotation for order 1), world velocity vel1 and angular
    velocity w1. Order 1: the body twist (v_b, ω_b) is constant, p₁ = p + R ∫₀ᵗexp(s[ω_b]×)ds v_b,
    R₁ = R exp(t[ω_b]×) (a straight line or an arc for the unicycle); order 2: p₁ = p + v t + ½ a t²."""
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
def barrier_value(di, df, dl, hb, grad, vel, closing, gain):
    """The barrier whose non-negativity is the safe set at one point, from hb = d - r - δ: hb itself,
    or for the braking barrier min(hb, h_b), h_b = hb - φ(s) with s the approach speed relative to
    the obstacle (``gain``: the row's gains, which set the speed floor). The rows keep h_b ≥ 0; a
    receding robot (s < 0) is credited φ(s) < 0, so h_b ≥ 0 alone would call a robot inside an
    obstacle that backs out safe. With hb ≥ 0 as well it is: h falls only while s > 0, and then
    hb ≥ φ(s) > 0 (``barriers.DoubleIntegrator``)."""
    if di[DescInts.BARRIER] != BRAKING:
        return hb
    brake = view1(df, dl, _D.brake)
    hdot = grad[0] * vel[0] + grad[1] * vel[1] + grad[2] * vel[2] - closing
    return min(hb, hb - braking(-hdot, speed_floor(brake, gain), brake[A_BRAKE])[0])


@jit
def barriers(di, df, dl, dist, grad, vel, gains, closing, delta, margins, age, hb):
    """hb_i = d_i - r_i - δ (- the group's margin) (- σ_i · age: the obstacle's motion since the
    map) at the body points, into hb; returns the critical point (smallest barrier value)."""
    radii = view1(df, dl, _D.radii)
    kbest, best = 0, math.inf
    for i in range(radii.shape[0]):
        hb[i] = dist[i] - radii[i] - delta
        if margins:
            hb[i] = hb[i] - gains[i, MARGIN]
        if closing[i] > 0.0:
            hb[i] = hb[i] - closing[i] * age
        val = barrier_value(di, df, dl, hb[i], grad[i], vel, closing[i], gains[i])
        if val < best or i == 0:
            kbest, best = i, val
    return kbest


@jit
def point_row(di, df, dl, rot, ang, vel, i, grad, hess, hb, gain, closing, a_row):
    """The CBF row a·u ≥ b of body point i (module docstring) with the field sample (grad, hess)
    and gains [α, α₁, α₂, margin] of its row, the barrier hb = d - r - δ of point i and the
    obstacle's closing speed σ there: writes a into a_row, returns b. ``rot`` is the attitude
    rotation, ``ang`` the reference's body rates. The only place the rows are written down."""
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
        return -gain[ALPHA] * hb - (lfh - closing)  # ḣ = L_f h + L_g h u + ∂h/∂t ≥ -α h
    curv = 0.0
    for a in range(3):
        for b in range(3):
            curv += vel[a] * hess[a, b] * vel[b]
    hdot = grad[0] * vel[0] + grad[1] * vel[1] + grad[2] * vel[2] - closing
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
            # obstacle (on the sim point cloud of the safety benchmark 0.74 of the roll-outs
            # collided with κ, 0.02 with this, as with ``hocbf``). A fixed floor keeps κ: the
            # braking barrier as it was before issue 25.
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
def point_rows(di, df, dl, rot, ang, vel, grad, hess, hb, gains, closing, a, b):
    """Rows of every body point i with the field sample i (grad, hess, gains, closing row i)."""
    for i in range(hb.shape[0]):
        b[i] = point_row(di, df, dl, rot, ang, vel, i, grad[i], hess[min(i, hess.shape[0] - 1)], hb[i], gains[i],
                         closing[i], a[i])


@jit
def closing_speeds(pts, dist, grad, rgq, gains, npts, objects, nobj, match, closing):
    """σ_j ≥ 0 at each field sample j: the largest speed at which a moving object that is the
    nearest obstacle there comes closer along ∇d. An object is the nearest obstacle of sample j
    when it is of the risk group the field records there and the field's distance agrees with
    the object's geometry: |horizontal distance to its centre - radius - the group's inflation
    margin - d_j| ≤ ``match`` (m)."""
    for j in range(npts):
        c = 0.0
        for k in range(nobj):
            if int(objects[k, OBJ_GROUP]) != rgq[j]:
                continue
            dx, dy = pts[j, 0] - objects[k, OBJ_X], pts[j, 1] - objects[k, OBJ_Y]
            gap = math.sqrt(dx * dx + dy * dy) - objects[k, OBJ_RADIUS] - gains[j, MARGIN]
            if abs(gap - dist[j]) > match:
                continue
            s = grad[j, 0] * objects[k, OBJ_VX] + grad[j, 1] * objects[k, OBJ_VY] + grad[j, 2] * objects[k, OBJ_VZ]
            c = max(c, s)
        closing[j] = c


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
def backup_input(di, df, dl, grad, vel, dt, a_row, closing, out):
    """The maximal braking along the gradient of one row: order 2 accelerates at a_max along ∇d
    (norm a_max: inside the per-axis box); order 1 stops at once (u = 0: no point moves deeper) —
    unless the obstacle itself comes closer (closing speed > 0), where stopping is not the safest:
    then backing away as fast as the box allows, by the inputs that translate the body (the bound
    that raises that row's a·u; turning inputs stay 0: a swing that helps the row's linearisation
    can carry the body towards the object)."""
    n = di[DescInts.N]
    if di[DescInts.ORDER] == 1:
        lo, hi, lin = view1(df, dl, _D.lo), view1(df, dl, _D.hi), view2(df, dl, _D.lin)
        for j in range(n):
            out[j] = 0.0
            moves = lin[0, j] != 0.0 or lin[1, j] != 0.0 or lin[2, j] != 0.0
            if closing > 0.0 and moves:
                out[j] = hi[j] if a_row[j] > 0.0 else (lo[j] if a_row[j] < 0.0 else 0.0)
        return
    gn = math.sqrt(grad[0] ** 2 + grad[1] ** 2 + grad[2] ** 2)
    if gn > 1e-9:
        a_max = view1(df, dl, _D.brake)[A_MAX]
        for j in range(n):
            out[j] = a_max * grad[j] / gn
    else:
        brake_input(di, df, dl, vel, dt, out)
