"""The filter step as compiled code (numba): field query, barrier rows and the exact QP.

:class:`CompiledStep` is the step of :class:`SafetyFilter <.filter.SafetyFilter>`: the barrier
points now and one period ahead, the query of an :class:`~riskfield.services.fields.grid.EsdfField`
(``protocol.field.query_point``: stencil, border extrapolation, trilinear or cubic kernel), the
CBF rows per model, the dropping of rows that hold on the whole box, the dual active-set QP, the
soft predictive rows and the slack relaxation, in one ``numba.njit`` call over preallocated
buffers, so a step allocates nothing in Python but its result. Any other ``DistanceField`` (an
analytic field, a point cloud) is queried by its own ``query`` between the two kernels
(:func:`points_kernel`, then :func:`step_kernel`), and everything else is the same code.

The model (its points, motion, barrier values and rows) comes from its one description through
the functions of ``model``. ``tests/oracles/filter_step.py`` is a numpy rendering of the same
step that ``tests/safety_filter/test_compiled.py`` compares against on random states, fields and
references for every model, and OSQP is the oracle of the QP.

The QP, in the model's input u ∈ Rⁿ::

    minimise   ½ (u - u_ref)ᵀ W (u - u_ref)        W = diag(w), w > 0   (λv, λω of the paper)
    subject to A u ≥ b                              one row per barrier point
               lo ≤ u ≤ hi                          input bounds

With z = W^½ (u - u_ref) it is the projection of the origin onto a polytope {z : C z ≥ d}
(general rows and bound rows alike), solved exactly by the Goldfarb–Idnani dual active-set
method: start at the unconstrained optimum z = 0, repeatedly add the most violated row and take
the step that keeps the current rows active and their multipliers non-negative (dropping a row
whose multiplier would turn negative). Each iteration solves a system of at most the active rows;
it ends with the exact optimum, or proves infeasibility when a violated row can be satisfied
neither by a primal step nor by releasing an active row. A single row is solved in closed form
along its breakpoints (:func:`_one_row`). Numerical trouble (a singular system, the iteration
limit) is reported as ``solver_failed`` and the step brakes.

The buffers are laid out once (:data:`FLOATS`, :data:`INTS`: ``protocol.kernels.Layout``), and
each phase of the step carves the views it needs by slot name. The kernels are compiled (or
loaded from numba's on-disk cache) when the filter is built, in the node's setup, never in the
control loop.
"""

from __future__ import annotations

import math

import numpy as np

from riskfield.protocol.field import QUERY_SCRATCH_SIZE, kernel_view, query_point
from riskfield.protocol.kernels import Layout, view1, view2, view3

from ..fields.grid import EsdfField
from ..runtime.jit import HAVE_NUMBA, jit
from . import model as mdl
from .model import GAIN_COLUMNS, OBJECT_COLUMNS, YIELD, DescInts
from .state import FilterState

# Outcome codes of the kernel (INTS "out"[0]).
OK, SLACK, OUTSIDE_MAP, NON_FINITE, INFEASIBLE, SOLVER_FAILED = 0, 1, 2, 3, 4, 5
FALLBACK = {OK: None, SLACK: "slack", OUTSIDE_MAP: "outside_map", NON_FINITE: "non_finite",
            INFEASIBLE: "infeasible", SOLVER_FAILED: "solver_failed"}
#: The solver's name in a step's result.
SOLVER = "active_set"
#: Rows of A u ≥ b may be violated by at most this much (absolute) in an accepted solution.
FEASIBILITY_TOL = 1e-6
#: Moving objects one step takes at most (``motion.object_table`` keeps the nearest), and the
#: most of them on a collision course that get a row (``max_object_rows``).
MAX_OBJECTS = 16

#: Iterations of the dual active-set method before it reports failure (INTS "max_iter").
QP_MAX_ITER = 50
_TOL = 1e-12

#: The float workspace of one filter's step. Dimensions: n inputs, m body points, q = 2m field
#: samples (the points now and one period ahead), K objects with rows (two each), s = q + 2K
#: samples (the objects' analytic ones after the field's), r = q + 2K CBF rows, rows = r + 2n QP
#: rows with the box, k objects, d the packed description's length.
FLOATS = Layout("Floats", [
    # the model's description (``model.DESC``), written once
    ("desc", ("d",)),
    # inputs of a step (CompiledStep.run)
    ("position", (3,)), ("rotation", (3, 3)), ("velocity", (3,)), ("u_ref", ("n",)), ("ang", (3,)),
    ("objects", ("k", OBJECT_COLUMNS)),
    # constants of the filter (δ per map: CompiledStep.prepare)
    ("delta", (1,)), ("alpha_cap", (1,)), ("dt", (1,)), ("horizon", (1,)), ("a_stop", (1,)), ("sweep", (1,)),
    # outputs: [h at the critical point, the barrier there], u
    ("out", (2,)), ("u", ("n",)),
    # scratch
    ("pts", ("q", 3)), ("dist", ("q",)), ("grad", ("s", 3)), ("hess", ("s", 3, 3)), ("gains", ("s", GAIN_COLUMNS)),
    ("hb", ("m",)), ("A", ("r", "n")), ("B", ("r",)), ("A2", ("r", "n")), ("B2", ("r",)),
    ("u_box", ("n",)), ("u_bk", ("n",)), ("u_c", ("n",)), ("u_stop", ("n",)), ("lo", ("n",)), ("hi", ("n",)),
    ("rot", (3, 3)), ("rot1", (3, 3)), ("s1", (3, 3)), ("s2", (3, 3)), ("pos1", (3,)), ("vel1", (3,)), ("w1", (3,)),
    ("still", (3,)), ("wobj", (3,)), ("v_ref", (3,)), ("when", ("k",)),
    ("query", (QUERY_SCRATCH_SIZE,)),
    ("rc", ("rows", "n")), ("rd", ("rows",)), ("norms", ("rows",)), ("gram", (8, 8)), ("aug", (8, 9)),
    ("z", ("n",)), ("rhs", (8,)), ("rr", (8,)), ("step", ("n",)), ("lam", (8,)), ("marks", ("n2",)), ("sw", ("n",)),
])
#: The integer workspace: the description's integers, the filter's switches, the object count,
#: whether the caller queried the field itself (:meth:`CompiledStep.run`), the QP's iteration limit,
#: the outputs [code, risk group, rows, intervening, yielding, object rows] and scratch (per row: its
#: sample, whether it yields).
INTS = Layout("Ints", [
    ("desc", (len(DescInts),)), ("predictive", (1,)), ("margins", (1,)), ("slack", (1,)), ("first_order", (1,)),
    ("nobj", (1,)), ("max_rows", (1,)), ("queried", (1,)), ("max_iter", (1,)), ("out", (6,)),
    ("rgq", ("q",)), ("inside", ("q",)), ("active", (8,)), ("rsrc", ("r",)), ("rsrc2", ("r",)), ("seen", ("r",)),
    ("ryield", ("r",)), ("ryield2", ("r",)),
])
F, I, D = FLOATS.slot, INTS.slot, mdl.DESC.slot


def workspace(m: int, n: int, k_rows: int = MAX_OBJECTS) -> tuple[np.ndarray, np.ndarray]:
    """(float table, int table) of :data:`FLOATS` and :data:`INTS` for m points, n inputs and at
    most ``k_rows`` object rows."""
    d = Layout.size(mdl.DESC.table(n=n, m=m))
    q = 2 * m
    r = q + 2 * k_rows
    return (FLOATS.table(d=d, n=n, m=m, q=q, s=r, r=r, rows=r + 2 * n, k=MAX_OBJECTS, n2=2 * n),
            INTS.table(q=q, r=r))


# --------------------------------------------------------------------------- the QP


@jit
def _one_row(w, r, a, b, lo, hi, n, u, marks):
    """One row and the box: the multiplier μ of the row found along its breakpoints, where a bound
    starts or stops binding; status 0 solved, 1 infeasible."""
    g = 0.0
    for j in range(n):
        u[j] = min(max(r[j], lo[j]), hi[j])
        g += a[j] * u[j]
    if g >= b - FEASIBILITY_TOL * (1.0 + abs(b)):
        return 0
    nm = 0
    for j in range(n):
        sl = a[j] / w[j]
        if sl != 0.0:
            for bound in (lo[j], hi[j]):
                mk = (bound - r[j]) / sl
                if 0.0 < mk < math.inf:
                    dup = False
                    for q in range(nm):
                        if marks[q] == mk:
                            dup = True
                    if not dup:
                        marks[nm] = mk
                        nm += 1
    for q in range(1, nm):  # insertion sort of ≤ 6 breakpoints
        v = marks[q]
        e = q - 1
        while e >= 0 and marks[e] > v:
            marks[e + 1] = marks[e]
            e -= 1
        marks[e + 1] = v
    mu_prev, g_prev = 0.0, g
    for kk in range(nm + 1):
        mu = marks[kk] if kk < nm else math.inf
        mid = 2.0 * mu_prev + 1.0 if mu == math.inf else 0.5 * (mu_prev + mu)
        slope = 0.0
        for j in range(n):
            sl = a[j] / w[j]
            x = r[j] + mid * sl
            if lo[j] < x < hi[j]:
                slope += a[j] * sl
        if mu != math.inf:
            g_next = g_prev + slope * (mu - mu_prev)
        else:
            g_next = math.inf if slope > 0 else g_prev
        if g_next >= b:
            mu_star = mu_prev + (b - g_prev) / slope
            g = 0.0
            for j in range(n):
                u[j] = min(max(r[j] + mu_star * (a[j] / w[j]), lo[j]), hi[j])
                g += a[j] * u[j]
            if g < b - FEASIBILITY_TOL * (1.0 + abs(b)):
                return 1
            return 0
        mu_prev, g_prev = mu, g_next
    return 1


@jit
def _solve_small(gram, rhs, q, aug, x):
    """Gaussian elimination with partial pivoting; False if singular."""
    scale = 0.0
    for i in range(q):
        for c in range(q):
            aug[i, c] = gram[i, c]
            scale = max(scale, abs(gram[i, c]))
        aug[i, q] = rhs[i]
    if scale == 0.0:
        scale = 1.0
    for col in range(q):
        piv = col
        for i in range(col + 1, q):
            if abs(aug[i, col]) > abs(aug[piv, col]):
                piv = i
        if abs(aug[piv, col]) <= 1e-12 * scale:
            return False
        if piv != col:
            for c in range(q + 1):
                tmp = aug[col, c]
                aug[col, c] = aug[piv, c]
                aug[piv, c] = tmp
        for i in range(col + 1, q):
            f = aug[i, col] / aug[col, col]
            for c in range(col, q + 1):
                aug[i, c] -= f * aug[col, c]
    for i in range(q - 1, -1, -1):
        s = 0.0
        for c in range(i + 1, q):
            s += aug[i, c] * x[c]
        x[i] = (aug[i, q] - s) / aug[i, i]
    return True


@jit
def _dual_active_set(wf, wi, lf, li, nr, n):
    """The dual active-set iteration (module docstring) on the scaled rows (FLOATS rc, rd) into z:
    status 0 solved, 1 infeasible, 2 failed."""
    rc, rd, z, norms = view2(wf, lf, F.rc), view1(wf, lf, F.rd), view1(wf, lf, F.z), view1(wf, lf, F.norms)
    lam, gram, rhs, rr = view1(wf, lf, F.lam), view2(wf, lf, F.gram), view1(wf, lf, F.rhs), view1(wf, lf, F.rr)
    step, aug, active = view1(wf, lf, F.step), view2(wf, lf, F.aug), view1(wi, li, I.active)
    for i in range(nr):
        s = 0.0
        for j in range(n):
            s += rc[i, j] * rc[i, j]
        norms[i] = max(math.sqrt(s), _TOL)
    for j in range(n):
        z[j] = 0.0
    na = 0
    it = 0
    max_iter = view1(wi, li, I.max_iter)[0]
    while it < max_iter:
        p, worst = -1, -FEASIBILITY_TOL
        for i in range(nr):
            s = 0.0
            for j in range(n):
                s += rc[i, j] * z[j]
            s = (s - rd[i]) / norms[i]
            if s < worst:
                p, worst = i, s
        if p < 0:
            return 0
        lam_p = 0.0
        while it < max_iter:
            it += 1
            if na > 0:
                if na >= gram.shape[0]:
                    return 2
                for e in range(na):
                    for f in range(na):
                        s = 0.0
                        for j in range(n):
                            s += rc[active[e], j] * rc[active[f], j]
                        gram[e, f] = s
                    s = 0.0
                    for j in range(n):
                        s += rc[active[e], j] * rc[p, j]
                    rhs[e] = s
                if not _solve_small(gram, rhs, na, aug, rr):
                    return 2
                for j in range(n):
                    s = 0.0
                    for e in range(na):
                        s += rr[e] * rc[active[e], j]
                    step[j] = rc[p, j] - s
            else:
                for j in range(n):
                    step[j] = rc[p, j]
            t1, drop = math.inf, -1
            for e in range(na):
                if rr[e] > 1e-12 and lam[e] / rr[e] < t1:
                    t1, drop = lam[e] / rr[e], e
            zz = 0.0
            slack = 0.0
            for j in range(n):
                zz += step[j] * step[j]
                slack += rc[p, j] * z[j]
            slack -= rd[p]
            t2 = -slack / zz if zz > 1e-12 * norms[p] ** 2 else math.inf
            if t1 == math.inf and t2 == math.inf:
                return 1
            t = min(t1, t2)
            if t2 != math.inf:
                for j in range(n):
                    z[j] = z[j] + t * step[j]
            for e in range(na):
                lam[e] -= t * rr[e]
            lam_p += t
            if t2 <= t1:
                active[na] = p
                lam[na] = lam_p
                na += 1
                break
            for e in range(drop, na - 1):  # release the row whose multiplier reached 0
                active[e] = active[e + 1]
                lam[e] = lam[e + 1]
            na -= 1
    return 2


@jit
def _active_set(wf, wi, lf, li, dl, n, nrow):
    """The exact QP (module docstring): into u the input closest to u_ref (the description's
    weights) in the box (FLOATS lo, hi) that keeps the live rows A2[:nrow], B2; status 0 solved,
    1 infeasible, 2 failed."""
    w, r = view1(view1(wf, lf, F.desc), dl, D.weights), view1(wf, lf, F.u_ref)
    A, b, lo, hi, u = view2(wf, lf, F.A2), view1(wf, lf, F.B2), view1(wf, lf, F.lo), view1(wf, lf, F.hi), \
        view1(wf, lf, F.u)
    rc, rd, z, sw = view2(wf, lf, F.rc), view1(wf, lf, F.rd), view1(wf, lf, F.z), view1(wf, lf, F.sw)
    if nrow == 1:
        return _one_row(w, r, A[0], b[0], lo, hi, n, u, view1(wf, lf, F.marks))
    for j in range(n):
        sw[j] = math.sqrt(w[j])
    nr = 0
    for i in range(nrow):
        s = 0.0
        for j in range(n):
            rc[nr, j] = A[i, j] / sw[j]
            s += A[i, j] * r[j]
        rd[nr] = b[i] - s
        nr += 1
    for j in range(n):
        if lo[j] > -math.inf:
            for c in range(n):
                rc[nr, c] = 1.0 if c == j else 0.0
            rd[nr] = sw[j] * (lo[j] - r[j])
            nr += 1
        if hi[j] < math.inf:
            for c in range(n):
                rc[nr, c] = -1.0 if c == j else 0.0
            rd[nr] = -sw[j] * (hi[j] - r[j])
            nr += 1
    dmax = -math.inf
    for i in range(nr):
        dmax = max(dmax, rd[i])
    if dmax <= FEASIBILITY_TOL:
        for j in range(n):
            u[j] = r[j]
        return 0
    status = _dual_active_set(wf, wi, lf, li, nr, n)
    if status != 0:
        return status
    for j in range(n):
        u[j] = min(max(r[j] + z[j] / sw[j], lo[j]), hi[j])
    if nrow > 0:
        scale = 0.0
        worst = math.inf
        for i in range(nrow):
            if math.isfinite(b[i]):
                scale = max(scale, abs(b[i]))
            s = 0.0
            for j in range(n):
                s += A[i, j] * u[j]
            worst = min(worst, s - b[i])
        if worst < -FEASIBILITY_TOL * (1.0 + scale):
            return 2
    return 0


@jit
def _worst_row(A, B, nrows, n, u):
    """min_i (a_iᵀu - b_i)/max(|a_i|, 1e-9) over the rows."""
    worst = math.inf
    for i in range(nrows):
        au, nn = 0.0, 0.0
        for j in range(n):
            au += A[i, j] * u[j]
            nn += A[i, j] * A[i, j]
        worst = min(worst, (au - B[i]) / max(math.sqrt(nn), 1e-9))
    return worst




@jit
def qp_kernel(wf, wi, lf, li, dl, n, nrow):
    """The exact QP alone, on rows a caller wrote (FLOATS A2[:nrow], B2, u_ref, lo, hi): the status."""
    return _active_set(wf, wi, lf, li, dl, n, nrow)


class ExactQP:
    """The filter's exact QP for a caller with rows of its own (the authors' protocol's HOCBF):
    min ½ (u - u_ref)ᵀ diag(weights) (u - u_ref) s.t. A u ≥ b, lo ≤ u ≤ hi, at most ``max_rows`` rows."""

    STATUS = ("solved", "infeasible", "failed")

    def __init__(self, weights: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_rows: int):
        if not HAVE_NUMBA:
            raise ModuleNotFoundError("No module named 'numba' (the filter's QP is compiled)", name="numba")
        self.n = n = len(weights)
        self.dl = mdl.DESC.table(n=n, m=1)
        self.lf, self.li = workspace(1, n, max(1, -(-(max_rows - 2) // 2)))
        self.max_rows = int(self.lf[F.B2, 1])
        self.wf, self.wi = np.zeros(Layout.size(self.lf)), np.zeros(Layout.size(self.li), np.int64)
        desc = FLOATS.view(self.wf, self.lf, "desc")
        mdl.DESC.view(desc, self.dl, "weights")[:] = weights
        FLOATS.view(self.wf, self.lf, "lo")[:], FLOATS.view(self.wf, self.lf, "hi")[:] = lo, hi
        self.u_ref, self.u = FLOATS.view(self.wf, self.lf, "u_ref"), FLOATS.view(self.wf, self.lf, "u")
        self.a, self.b = FLOATS.view(self.wf, self.lf, "A2"), FLOATS.view(self.wf, self.lf, "B2")
        INTS.view(self.wi, self.li, "max_iter")[0] = QP_MAX_ITER

    def solve(self, u_ref: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[str, np.ndarray]:
        """(status: solved, infeasible or failed, u)."""
        rows = len(b)
        if rows > self.max_rows:
            raise ValueError(f"{rows} rows: this QP holds at most {self.max_rows}")
        self.u_ref[:] = u_ref
        self.a[:rows], self.b[:rows] = a, b
        status = qp_kernel(self.wf, self.wi, self.lf, self.li, self.dl, self.n, rows)
        return self.STATUS[status], self.u.copy()


# --------------------------------------------------------------------------- the step, in phases


@jit
def _scalar(wf, lf, k):
    return view1(wf, lf, k)[0]


@jit
def _begin(wf, lf, dl, n):
    """Inputs finite (anything non-finite brakes) and the reference clipped into the box (u_box).
    Returns the outcome code, or -1 to go on."""
    u_ref, ang = view1(wf, lf, F.u_ref), view1(wf, lf, F.ang)
    for j in range(n):
        if not math.isfinite(u_ref[j]):
            return NON_FINITE
    for j in range(3):
        if not math.isfinite(ang[j]):
            return NON_FINITE
    pos, rot, vel = view1(wf, lf, F.position), view2(wf, lf, F.rotation), view1(wf, lf, F.velocity)
    for a in range(3):
        if not (math.isfinite(pos[a]) and math.isfinite(vel[a])):
            return NON_FINITE
        for b in range(3):
            if not math.isfinite(rot[a, b]):
                return NON_FINITE
    df = view1(wf, lf, F.desc)
    lo, hi, u_box = view1(df, dl, D.lo), view1(df, dl, D.hi), view1(wf, lf, F.u_box)
    for j in range(n):
        u_box[j] = min(max(u_ref[j], lo[j]), hi[j])
    _full_box(wf, lf, dl, n)
    return -1


@jit
def _full_box(wf, lf, dl, n):
    """The QP's box (FLOATS lo, hi): the model's."""
    df = view1(wf, lf, F.desc)
    lo0, hi0, lo, hi = view1(df, dl, D.lo), view1(df, dl, D.hi), view1(wf, lf, F.lo), view1(wf, lf, F.hi)
    for j in range(n):
        lo[j], hi[j] = lo0[j], hi0[j]


@jit
def _points(wf, wi, lf, li, dl, predictive):
    """The barrier points now (samples 0..m-1) and one period ahead under u_box (m..2m-1)."""
    di, df = view1(wi, li, I.desc), view1(wf, lf, F.desc)
    pos, rot, vel = view1(wf, lf, F.position), view2(wf, lf, F.rotation), view1(wf, lf, F.velocity)
    pts, r = view2(wf, lf, F.pts), view2(wf, lf, F.rot)
    mdl.attitude_rotation(di, rot, r)
    mdl.place_points(df, dl, pos, r, pts, 0)
    if predictive:
        pos1, rot1, r1 = view1(wf, lf, F.pos1), view2(wf, lf, F.rot1), view2(wf, lf, F.s1)
        mdl.flow((di, df, dl), (pos, rot, vel), view1(wf, lf, F.u_box), view1(wf, lf, F.ang), _scalar(wf, lf, F.dt),
                 (pos1, rot1, view1(wf, lf, F.vel1), view1(wf, lf, F.w1)), (r1, view2(wf, lf, F.s2)))
        mdl.attitude_rotation(di, rot1, r1)
        mdl.place_points(df, dl, pos1, r1, pts, di[DescInts.M])


@jit
def points_kernel(wf, wi, lf, li, dl):
    """The step up to the field query: the inputs checked, u_box, and the barrier points now
    (samples 0..m-1) and, with predictive rows, one period ahead (m..2m-1). Returns the outcome
    code, or -1 to go on."""
    di = view1(wi, li, I.desc)
    code = _begin(wf, lf, dl, di[DescInts.N])
    if code >= 0:
        return code
    predictive = view1(wi, li, I.predictive)[0] != 0
    _points(wf, wi, lf, li, dl, predictive)
    pts = view2(wf, lf, F.pts)
    for i in range(2 * di[DescInts.M] if predictive else di[DescInts.M]):
        for a in range(3):
            if not math.isfinite(pts[i, a]):
                return NON_FINITE
    return -1


@jit
def _sample(wf, wi, lf, li, field, table, npts, order):
    """The field at every sample (unless the caller queried it: INTS "queried") and the gains of
    their groups (capped for first-order models)."""
    pts, dist, grad, hess = view2(wf, lf, F.pts), view1(wf, lf, F.dist), view2(wf, lf, F.grad), view3(wf, lf, F.hess)
    rgq, inside, gains = view1(wi, li, I.rgq), view1(wi, li, I.inside), view2(wf, lf, F.gains)
    out, scratch = (dist, grad, hess, rgq, inside), view1(wf, lf, F.query)
    if view1(wi, li, I.queried)[0] == 0:
        k = 3 if order == 2 else 2
        for i in range(npts):
            query_point(field, k, pts[i], i, out, scratch)
    nt = table.shape[0]
    cap = _scalar(wf, lf, F.alpha_cap)
    first_order = view1(wi, li, I.first_order)[0]
    for i in range(npts):
        g = min(rgq[i], nt - 1)
        for c in range(GAIN_COLUMNS):
            gains[i, c] = table[g, c]
        if first_order:
            gains[i, 0] = min(gains[i, 0], cap)


@jit
def _rows(wf, wi, lf, li, dl, m, n, predictive):
    """The CBF rows (``model.point_row``) of the points now and, where the gradient or group one
    period ahead differs, of the points ahead (filter's predictive rows), each marked yielding by
    its group. Returns the row count."""
    di, df = view1(wi, li, I.desc), view1(wf, lf, F.desc)
    rot, ang, vel = view2(wf, lf, F.rot), view1(wf, lf, F.ang), view1(wf, lf, F.velocity)
    desc, motion = (di, df, dl), (rot, ang, vel)
    grad, hess, gains = view2(wf, lf, F.grad), view3(wf, lf, F.hess), view2(wf, lf, F.gains)
    hb, still, A, B = view1(wf, lf, F.hb), view1(wf, lf, F.still), view2(wf, lf, F.A), view1(wf, lf, F.B)
    rgq, inside, rsrc = view1(wi, li, I.rgq), view1(wi, li, I.inside), view1(wi, li, I.rsrc)
    ryield = view1(wi, li, I.ryield)
    for i in range(m):
        B[i] = mdl.point_row(desc, motion, i, grad[i], hess[i], hb[i], gains[i], still, A[i])
        rsrc[i] = i
        ryield[i] = gains[i, YIELD] > 0.0
    nrows = m
    if predictive:
        for i in range(m):
            j = m + i
            diff = 0.0
            for a in range(3):
                diff = max(diff, abs(grad[j, a] - grad[i, a]))
            same = diff < 0.05 and rgq[j] == rgq[i]
            if inside[j] and not same:
                B[nrows] = mdl.point_row(desc, motion, i, grad[j], hess[j], hb[i], gains[j], still, A[nrows])
                rsrc[nrows] = j
                ryield[nrows] = gains[j, YIELD] > 0.0
                nrows += 1
    return nrows


@jit
def _object_rows(wf, wi, lf, li, dl, m, n, nrows, table):
    """The rows of the moving objects on a collision course (``model.object_course``), the
    ``max_rows`` soonest first, each with its own two analytic rows (``model.object_sample``: its
    body, then the capsule it sweeps) as samples 2m + 2r, 2m + 2r + 1; all yield. Returns (the
    row count, the objects with rows)."""
    di, df = view1(wi, li, I.desc), view1(wf, lf, F.desc)
    rot, ang, vel = view2(wf, lf, F.rot), view1(wf, lf, F.ang), view1(wf, lf, F.velocity)
    desc, motion = (di, df, dl), (rot, ang, vel)
    pts, grad, hess, gains = view2(wf, lf, F.pts), view2(wf, lf, F.grad), view3(wf, lf, F.hess), view2(wf, lf, F.gains)
    objects, when, v_ref, wobj = view2(wf, lf, F.objects), view1(wf, lf, F.when), view1(wf, lf, F.v_ref), \
        view1(wf, lf, F.wobj)
    A, B, rsrc, ryield = view2(wf, lf, F.A), view1(wf, lf, F.B), view1(wi, li, I.rsrc), view1(wi, li, I.ryield)
    nobj, kmax = view1(wi, li, I.nobj)[0], view1(wi, li, I.max_rows)[0]
    delta, horizon, a_stop = _scalar(wf, lf, F.delta), _scalar(wf, lf, F.horizon), _scalar(wf, lf, F.a_stop)
    sweep = _scalar(wf, lf, F.sweep)
    nt = table.shape[0]
    mdl.reference_velocity(di, df, dl, rot, vel, view1(wf, lf, F.u_box), v_ref)
    for k in range(nobj):
        g = min(int(objects[k, mdl.OBJ_GROUP]), nt - 1)
        when[k] = mdl.object_course(desc, pts, v_ref, vel, objects[k], table[g, mdl.MARGIN], delta, horizon, a_stop)
    cap = _scalar(wf, lf, F.alpha_cap)
    first_order = view1(wi, li, I.first_order)[0]
    made = 0
    while made < kmax:
        best, kb = math.inf, -1
        for k in range(nobj):  # the soonest left (the first on ties, as a stable sort)
            if when[k] < best:
                best, kb = when[k], k
        if kb < 0:
            break
        when[kb] = math.inf
        j = 2 * m + 2 * made
        g = min(int(objects[kb, mdl.OBJ_GROUP]), nt - 1)
        for c in range(GAIN_COLUMNS):
            gains[j, c] = table[g, c]
        if first_order:
            gains[j, 0] = min(gains[j, 0], cap)
        for c in range(GAIN_COLUMNS):
            gains[j + 1, c] = gains[j, c]
        for part in range(2):  # its body, then the capsule it sweeps (model.object_sample)
            jj = j + part
            i, hbo = mdl.object_sample(desc, pts, objects[kb], gains[jj], delta, sweep * part, grad[jj], hess[jj],
                                       wobj)
            B[nrows] = mdl.point_row(desc, motion, i, grad[jj], hess[jj], hbo, gains[jj], wobj, A[nrows])
            rsrc[nrows] = jj
            ryield[nrows] = 1
            nrows += 1
        made += 1
    return nrows, made


@jit
def _finite_rows(wf, lf, nrows, n):
    A, B = view2(wf, lf, F.A), view1(wf, lf, F.B)
    for i in range(nrows):
        ok = math.isfinite(B[i])
        for j in range(n):
            ok = ok and math.isfinite(A[i, j])
        if not ok:
            return False
    return True


@jit
def _clip_yielding(wf, wi, lf, li, dl, nrows, n):
    """Yielding rows clipped to what stopping achieves (``model.yield_clip``); True when one asked more."""
    di, df = view1(wi, li, I.desc), view1(wf, lf, F.desc)
    A, B, ryield, u_stop = view2(wf, lf, F.A), view1(wf, lf, F.B), view1(wi, li, I.ryield), view1(wf, lf, F.u_stop)
    mdl.brake_input(di, df, dl, view1(wf, lf, F.velocity), _scalar(wf, lf, F.dt), u_stop)
    yielding = False
    for i in range(nrows):
        if ryield[i]:
            B[i], clipped = mdl.yield_clip(di, A[i], B[i], u_stop)
            yielding = yielding or clipped
    return yielding


@jit
def _drop_inactive(wf, wi, lf, li, dl, nrows, n):
    """Rows that hold for every u in the box cannot be active: the others into A2, B2 (rsrc2,
    ryield2). Returns (their count, whether one of them yields)."""
    df = view1(wf, lf, F.desc)
    lo, hi = view1(df, dl, D.lo), view1(df, dl, D.hi)
    A, B, A2, B2 = view2(wf, lf, F.A), view1(wf, lf, F.B), view2(wf, lf, F.A2), view1(wf, lf, F.B2)
    rsrc, rsrc2 = view1(wi, li, I.rsrc), view1(wi, li, I.rsrc2)
    ryield, ryield2 = view1(wi, li, I.ryield), view1(wi, li, I.ryield2)
    nlive = 0
    any_yield = False
    for i in range(nrows):
        s = 0.0
        for j in range(n):
            s += min(A[i, j] * lo[j], A[i, j] * hi[j])
        if B[i] > s + 1e-12:
            for j in range(n):
                A2[nlive, j] = A[i, j]
            B2[nlive] = B[i]
            rsrc2[nlive] = rsrc[i]
            ryield2[nlive] = ryield[i]
            any_yield = any_yield or ryield[i] != 0
            nlive += 1
    return nlive, any_yield


@jit
def _relax(wf, wi, lf, li, dl, m, n, nlive):
    """An infeasible QP with the slack relaxation on (filter's module docstring): the backup u_bk —
    of the braking input and the maximal braking along each live row's (distinct) gradient, the
    one whose worst row does best — then the soft predictive rows, then every row relaxed to what
    u_bk achieves. Returns (status, outcome code)."""
    di, df = view1(wi, li, I.desc), view1(wf, lf, F.desc)
    vel, dt = view1(wf, lf, F.velocity), _scalar(wf, lf, F.dt)
    grad, A2, B2, B = view2(wf, lf, F.grad), view2(wf, lf, F.A2), view1(wf, lf, F.B2), view1(wf, lf, F.B)
    u_bk, u_c = view1(wf, lf, F.u_bk), view1(wf, lf, F.u_c)
    rsrc2, seen = view1(wi, li, I.rsrc2), view1(wi, li, I.seen)
    mdl.brake_input(di, df, dl, vel, dt, u_bk)
    best_score = _worst_row(A2, B2, nlive, n, u_bk)
    nseen = 0
    for i in range(nlive):
        src = rsrc2[i]
        new = True
        for s_ in range(nseen):
            o = seen[s_]
            diff = 0.0
            for a in range(3):
                diff = max(diff, abs(grad[src, a] - grad[o, a]))
            if diff <= 1e-6:
                new = False
                break
        if not new:
            continue
        seen[nseen] = src
        nseen += 1
        mdl.backup_input(di, df, dl, grad[src], vel, dt, u_c)
        score = _worst_row(A2, B2, nlive, n, u_c)
        if score > best_score:
            best_score = score
            for j in range(n):
                u_bk[j] = u_c[j]
    # Soft predictive rows: first relax only the rows ahead (m ≤ rsrc2 < 2m) that the backup
    # violates, keeping the current rows hard; B keeps the live rows' b meanwhile.
    soft = False
    status = 1
    for i in range(nlive):
        B[i] = B2[i]
        if m <= rsrc2[i] < 2 * m:
            ab = 0.0
            for j in range(n):
                ab += A2[i, j] * u_bk[j]
            if B2[i] > ab:
                B2[i] = ab
                soft = True
    if soft:
        status = _active_set(wf, wi, lf, li, dl, n, nlive)
        if status == 2:
            return 2, SOLVER_FAILED
        for i in range(nlive):
            B2[i] = B[i]
    blind = False
    for i in range(nlive):
        ab = 0.0
        amax = 0.0
        for j in range(n):
            ab += A2[i, j] * u_bk[j]
            amax = max(amax, abs(A2[i, j]))
        if B2[i] > ab and amax <= 1e-9:
            blind = True
        B2[i] = min(B2[i], ab)
    if status == 1 and not blind:
        status = _active_set(wf, wi, lf, li, dl, n, nlive)
        if status == 2:
            return 2, SOLVER_FAILED
        if status != 0:
            u = view1(wf, lf, F.u)
            for j in range(n):
                u[j] = u_bk[j]
            status = 0
        return status, SLACK
    return status, OK


@jit
def step_kernel(wf, wi, lf, li, dl, field, table):
    """One filter step (SafetyFilter.filter) over the workspaces ``wf``, ``wi`` (laid out by the
    tables ``lf``, ``li`` of :data:`FLOATS`, :data:`INTS`; ``dl`` the description's
    ``model.DESC`` table), the field as ``protocol.field.kernel_view`` gives it and the gains per
    risk group (``table``). Outcome in INTS "out" = [code, risk group, rows, intervening,
    yielding, object rows], FLOATS "out" = [h at the critical point, the barrier there] and "u"."""
    out_i, out_f = view1(wi, li, I.out), view1(wf, lf, F.out)
    for c in range(6):
        out_i[c] = 0
    out_f[0], out_f[1] = 0.0, 0.0
    di, df = view1(wi, li, I.desc), view1(wf, lf, F.desc)
    n, m, order = di[DescInts.N], di[DescInts.M], di[DescInts.ORDER]
    predictive = view1(wi, li, I.predictive)[0] != 0
    if view1(wi, li, I.queried)[0] == 0:
        code = points_kernel(wf, wi, lf, li, dl)
        if code >= 0:
            out_i[0] = code
            return
    _sample(wf, wi, lf, li, field, table, 2 * m if predictive else m, order)
    dist, grad, hb = view1(wf, lf, F.dist), view2(wf, lf, F.grad), view1(wf, lf, F.hb)
    rgq, inside = view1(wi, li, I.rgq), view1(wi, li, I.inside)
    kc = mdl.barriers((di, df, dl), dist, grad, view1(wf, lf, F.velocity), view2(wf, lf, F.gains),
                      _scalar(wf, lf, F.delta), view1(wi, li, I.margins)[0] != 0, hb, view1(wf, lf, F.still))
    h_crit = dist[kc] - view1(df, dl, D.radii)[kc]
    out_f[0], out_i[1] = h_crit, rgq[kc]
    for i in range(m):
        if not inside[i]:
            out_f[0] = 0.0
            out_i[0] = OUTSIDE_MAP
            return
    nrows = _rows(wf, wi, lf, li, dl, m, n, predictive)
    nrows, n_obj = _object_rows(wf, wi, lf, li, dl, m, n, nrows, table)
    if not _finite_rows(wf, lf, nrows, n) or not math.isfinite(h_crit):
        out_f[0] = 0.0
        out_i[0] = NON_FINITE
        return
    out_i[2], out_i[5] = nrows, n_obj
    out_i[4] = _clip_yielding(wf, wi, lf, li, dl, nrows, n)
    nlive, yielding_live = _drop_inactive(wf, wi, lf, li, dl, nrows, n)
    boxed = yielding_live and mdl.yield_box(di, df, dl, view1(wf, lf, F.u_ref), view1(wf, lf, F.lo),
                                            view1(wf, lf, F.hi))
    status = _active_set(wf, wi, lf, li, dl, n, nlive)
    if status == 1 and boxed:
        # The static rows ask more than slowing (recovery from inside a static margin): the full
        # box, the yielding rows still clipped.
        _full_box(wf, lf, dl, n)
        status = _active_set(wf, wi, lf, li, dl, n, nlive)
    code = OK
    if status == 2:
        out_i[0] = SOLVER_FAILED
        return
    if status == 1 and view1(wi, li, I.slack)[0] != 0:
        status, code = _relax(wf, wi, lf, li, dl, m, n, nlive)
        if code == SOLVER_FAILED:
            out_i[0] = SOLVER_FAILED
            return
    if status != 0:
        out_i[0] = INFEASIBLE
        return
    u, u_box = view1(wf, lf, F.u), view1(wf, lf, F.u_box)
    dev = 0.0
    for j in range(n):
        if not math.isfinite(u[j]):
            out_i[0] = NON_FINITE
            return
        dev = max(dev, abs(u[j] - u_box[j]))
    out_i[0] = code
    out_i[3] = 1 if (code != OK or dev > 1e-6) else 0
    out_f[1] = hb[kc]


# --------------------------------------------------------------------------- the Python side


class CompiledStep:
    """Preallocated buffers and constants of one filter's compiled step.

    ``run`` fills the input slots, calls the kernels and leaves the outcome in ``u``, ``out_f`` and
    ``out_i`` (:func:`step_kernel`); :meth:`SafetyFilter.filter <.filter.SafetyFilter.filter>`
    turns it into a ``FilterResult``. Built (and the kernels compiled or loaded from numba's
    cache) once per filter: :meth:`warm_up` runs it on a small grid.
    """

    def __init__(self, model, config, delta: float, alpha_cap: float):
        """``config`` is the filter's ``FilterConfig``; ``delta`` its sampled-data margin and
        ``alpha_cap`` the first-order models' gain cap (``SafetyFilter``)."""
        if not HAVE_NUMBA:
            raise ModuleNotFoundError("No module named 'numba' (the safety filter's step is compiled)", name="numba")
        m, n = model.m, model.n
        self.m, self.n, self.order = m, n, model.spec.order
        max_object_rows = max(config.max_object_rows if config.object_motion else 0, 1)
        self.lf, self.li = workspace(m, n, max_object_rows)
        self.dl = model.dl
        self.wf, self.wi = np.zeros(Layout.size(self.lf)), np.zeros(Layout.size(self.li), np.int64)
        di, df = model.spec.packed
        fv, iv = self._f, self._i
        fv("desc")[:] = df
        iv("desc")[:] = di
        # δ of the kernel = δ + map_margin_voxels · the voxel size of the field in hand (``prepare``).
        self.delta, self.map_margin_voxels = delta, config.map_margin_voxels
        fv("delta")[0] = delta
        fv("alpha_cap")[0] = alpha_cap if math.isfinite(alpha_cap) else 1e300
        fv("dt")[0], fv("horizon")[0] = config.dt, config.collision_horizon_s
        fv("a_stop")[0], fv("sweep")[0] = config.a_max, config.object_sweep_s
        iv("max_rows")[0], iv("max_iter")[0] = max_object_rows, QP_MAX_ITER
        iv("predictive")[0], iv("margins")[0] = config.predictive_rows, config.margins_in_filter
        iv("slack")[0] = config.slack
        iv("first_order")[0] = model.spec.order == 1
        self.position, self.rotation, self.velocity = fv("position"), fv("rotation"), fv("velocity")
        self.u_ref, self.ang, self.objects = fv("u_ref"), fv("ang"), fv("objects")
        self.nobj, self.queried = iv("nobj"), iv("queried")
        # Views of the outputs (step_kernel's docstring) and of the samples a caller's query fills.
        self.out_f, self.u, self.out_i = fv("out"), fv("u"), iv("out")
        self.pts, self.dist, self.grad, self.hess = fv("pts"), fv("dist"), fv("grad"), fv("hess")
        self.rgq, self.inside = iv("rgq"), iv("inside")
        self._field: tuple | None = None
        # The kernel's field argument when the caller queries the field itself: never read.
        self._unread = kernel_view(EsdfField(np.ones((2, 2, 2), np.float32), (0.0, 0.0, 0.0), 1.0))

    def _f(self, name: str) -> np.ndarray:
        return FLOATS.view(self.wf, self.lf, name)

    def _i(self, name: str) -> np.ndarray:
        return INTS.view(self.wi, self.li, name)

    def prepare(self, field: EsdfField) -> tuple:
        """The kernel's view of a field (``protocol.field.kernel_view``), kept per map."""
        if self._field is not None and self._field[0] is field:
            return self._field[1]
        view = kernel_view(field)
        self._field = (field, view)
        self._f("delta")[0] = self.delta + self.map_margin_voxels * field.voxel_size
        return view

    def run(self, state: FilterState, u_ref: np.ndarray, ang: np.ndarray, field, table: np.ndarray,
            objects: np.ndarray | None = None) -> None:
        """One step on ``state`` (a ``FilterState``). An ``EsdfField`` is queried inside the kernel;
        any other ``DistanceField`` (an analytic field, a point cloud) by its own ``query`` between
        :func:`points_kernel` and :func:`step_kernel`. ``objects`` (k × ``model.OBJECT_COLUMNS``, at
        most :data:`MAX_OBJECTS`) are the moving objects predicted to the instant the command takes
        effect (``motion.object_table``)."""
        self.position[:] = state.position
        self.rotation[:] = state.rotation
        self.velocity[:] = state.velocity
        self.u_ref[:] = u_ref
        self.ang[:] = ang
        k = 0 if objects is None else min(len(objects), MAX_OBJECTS)
        if k:
            self.objects[:k] = objects[:k]
        self.nobj[0] = k
        if isinstance(field, EsdfField):
            self.queried[0] = 0
            step_kernel(self.wf, self.wi, self.lf, self.li, self.dl, self.prepare(field), table)
            return
        self._field = None
        self.queried[0] = 1
        self.out_i[:] = 0
        code = points_kernel(self.wf, self.wi, self.lf, self.li, self.dl)
        if code >= 0:
            self.out_i[0] = code
            return
        npts = 2 * self.m if self._i("predictive")[0] else self.m
        sample = field.query(self.pts[:npts], hessian=self.order == 2)
        self.dist[:npts], self.grad[:npts] = sample.distance, sample.gradient
        self.hess[:npts] = 0.0 if sample.hessian is None else sample.hessian
        self.rgq[:npts], self.inside[:npts] = sample.risk_group, sample.inside
        self._f("delta")[0] = self.delta + self.map_margin_voxels * getattr(field, "voxel_size", 0.0)
        step_kernel(self.wf, self.wi, self.lf, self.li, self.dl, self._unread, table)

    def warm_up(self, table: np.ndarray) -> None:
        """Compile (or load from the on-disk cache) with the argument types of the control loop."""
        for planar in (True, False):
            shape = (4, 4, 1) if planar else (4, 4, 4)
            field = EsdfField(np.ones(shape, np.float32), (0.0, 0.0, 0.0), 0.1, interpolation="bspline_smooth")
            state = FilterState(np.array([0.15, 0.15, 0.0 if planar else 0.15]))
            self.run(state, np.zeros(self.n), np.zeros(3), field, table)
        points_kernel(self.wf, self.wi, self.lf, self.li, self.dl)  # the phase a field's own query follows
        self._field = None
