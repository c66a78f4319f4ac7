"""The filter step as one compiled call (numba): field query, barrier rows and the exact QP.

:class:`CompiledStep` runs what :meth:`SafetyFilter.filter <.filter.SafetyFilter>` does with
numpy — the same barrier points (and their predicted positions), the same query of an
:class:`~riskfield.services.fields.grid.EsdfField` (stencil, border extrapolation, trilinear or
cubic kernel of ``fields.spline``), the same CBF rows per model, the same dropping of rows that
hold on the whole box, the same dual active-set QP (``qp.ActiveSetSolver``), the soft
predictive rows and the slack relaxation — in a single ``numba.njit`` function over
preallocated buffers, so a step allocates nothing in Python but its result.

It is an accelerator, not a second definition: wherever the compiled step would leave the
numpy path's well-trodden cases it hands the step back (:data:`HANDBACK`) and the numpy path
decides — a non-finite state, an active-set failure that the numpy path sends to OSQP. Results
agree with the numpy path to rounding (sums run in another order than BLAS's), which the
property test in ``tests/safety_filter/test_compiled.py`` checks on random states, fields and
references for every model.

The field is queried by ``fields.compiled.query_point`` (the grid query for one point, in
machine code). The kernel is compiled (or loaded from numba's on-disk cache) when the filter is
built — in the node's setup — never in the control loop.
"""

from __future__ import annotations

import math

import numpy as np

from ..fields.compiled import HAVE_NUMBA, jit, kernel_view, query_point
from ..fields.grid import EsdfField
from .qp import FEASIBILITY_TOL

# Model kinds of the kernel.
UNICYCLE, SINGLE2D, SINGLE3D, DOUBLE_BRAKING, DOUBLE_HOCBF = 0, 1, 2, 3, 4
# Outcome codes of the kernel (out_i[0]).
OK, SLACK, OUTSIDE_MAP, NON_FINITE, INFEASIBLE, HANDBACK = 0, 1, 2, 3, 4, 9
FALLBACK = {OK: None, SLACK: "slack", OUTSIDE_MAP: "outside_map", NON_FINITE: "non_finite",
            INFEASIBLE: "infeasible"}


_MAX_ITER, _TOL = 50, 1e-12  # as qp.ActiveSetSolver's defaults


# --------------------------------------------------------------------------- SO(3) helpers


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
def _so3_exp(x, y, z, out):
    th = math.sqrt(x * x + y * y + z * z)
    if th < 1e-9:
        _series(x, y, z, 1.0, 1.0, 0.5, out)
    else:
        _series(x, y, z, 1.0, math.sin(th) / th, (1 - math.cos(th)) / th**2, out)


@jit
def _so3_integral(x, y, z, t, out):
    th = math.sqrt(x * x + y * y + z * z)
    if abs(th * t) < 1e-6:
        _series(x, y, z, t, 0.5 * t * t, t**3 / 6.0, out)
    else:
        _series(x, y, z, t, (1 - math.cos(th * t)) / th**2, (th * t - math.sin(th * t)) / th**3, out)


@jit
def _yaw_rot(yaw, out):
    c, s = math.cos(yaw), math.sin(yaw)
    out[:, :] = 0.0
    out[0, 0], out[0, 1], out[1, 0], out[1, 1], out[2, 2] = c, -s, s, c, 1.0


@jit
def _rigid_points(pos, rot, offsets, m, pts, row0):
    """pts[row0 + i] = pos + rot @ o_i."""
    for i in range(m):
        for a in range(3):
            pts[row0 + i, a] = pos[a] + rot[a, 0] * offsets[i, 0] + rot[a, 1] * offsets[i, 1] \
                + rot[a, 2] * offsets[i, 2]


# --------------------------------------------------------------------------- the QP (qp.ActiveSetSolver)


@jit
def _one_row(w, r, a, b, lo, hi, n, u, marks):
    """qp.ActiveSetSolver._one_row: status 0 solved, 1 infeasible."""
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
    """qp._solve_small: Gaussian elimination with partial pivoting; False if singular."""
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
def _dual_active_set(rc, rd, nr, n, z, norms, active, lam, gram, rhs, rr, step, aug):
    """qp.ActiveSetSolver._dual_active_set: status 0 solved, 1 infeasible, 2 failed."""
    for i in range(nr):
        s = 0.0
        for j in range(n):
            s += rc[i, j] * rc[i, j]
        norms[i] = max(math.sqrt(s), _TOL)
    for j in range(n):
        z[j] = 0.0
    na = 0
    it = 0
    while it < _MAX_ITER:
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
        while it < _MAX_ITER:
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
def _active_set(w, r, A, b, nrow, lo, hi, n, u, rc, rd, norms, gram, aug, z, rhs, rr, step, lam, marks, sw, active):
    """qp.ActiveSetSolver.solve on rows A[:nrow]: status 0 solved, 1 infeasible, 2 failed."""
    if nrow == 1:
        return _one_row(w, r, A[0], b[0], lo, hi, n, u, marks)
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
    status = _dual_active_set(rc, rd, nr, n, z, norms, active, lam, gram, rhs, rr, step, aug)
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


# --------------------------------------------------------------------------- the step


@jit
def _braking(approach, s0, a_brake):
    """(φ(s), φ'(s)) of the braking barrier (``DoubleIntegrator.braking_distance``)."""
    if approach >= s0:
        phi = (approach * approach + s0 * s0) / (2 * a_brake)
    else:
        phi = s0 * approach / a_brake
    return phi, max(approach, s0) / a_brake


@jit
def _rows(kind, n, m, i, src, rot, omega, offsets, centred, grad, hess, hb_i, gain, vel, a_brake, s0, ell, A, B,
          row):
    """The CBF row of point i (field sample in row src) into A[row], B[row] (barriers.*.rows)."""
    gx, gy, gz = grad[src, 0], grad[src, 1], grad[src, 2]
    if kind == UNICYCLE:
        c, s = rot[0, 0], rot[1, 0]
        ox, oy = offsets[i, 0], offsets[i, 1]
        A[row, 0] = gx * c + gy * s
        A[row, 1] = gx * -(s * ox + c * oy) + gy * (c * ox - s * oy)
        B[row] = -gain[0] * hb_i
    elif kind == SINGLE2D or kind == SINGLE3D:
        for j in range(n):
            A[row, j] = gx * rot[0, j] + gy * rot[1, j] + gz * rot[2, j]
        if centred:
            B[row] = -gain[0] * hb_i
        else:
            ox, oy, oz = offsets[i, 0], offsets[i, 1], offsets[i, 2]
            cx = omega[1] * oz - omega[2] * oy  # ω × o
            cy = omega[2] * ox - omega[0] * oz
            cz = omega[0] * oy - omega[1] * ox
            drift = 0.0
            for a in range(3):
                drift += (rot[a, 0] * cx + rot[a, 1] * cy + rot[a, 2] * cz) * grad[src, a]
            B[row] = -gain[0] * hb_i - drift
    else:
        curv = 0.0
        for a in range(3):
            for b in range(3):
                curv += vel[a] * hess[src, a, b] * vel[b]
        hdot = gx * vel[0] + gy * vel[1] + gz * vel[2]
        a1, a2 = gain[1], gain[2]
        disc = math.sqrt(max(a1 * a1 - 4 * a2, 0.0))
        if kind == DOUBLE_BRAKING:
            phi, cc = _braking(-hdot, s0, a_brake)
            hbrake = hb_i - phi
            kappa = 0.5 * (a1 - disc)
            rate = kappa * hbrake * (1.0 + max(hbrake, 0.0) / ell)  # α(h_b), DoubleIntegrator's docstring
            for a in range(3):
                A[row, a] = grad[src, a] * cc
            B[row] = -rate - hdot - cc * curv
        else:
            k_slow, k_fast = 0.5 * (a1 - disc), 0.5 * (a1 + disc)
            psi1 = hdot + k_fast * hb_i
            gamma = max(k_slow, k_fast + 2 * abs(psi1) / max(hb_i, 1e-3)) if psi1 < 0 else k_slow
            for a in range(3):
                A[row, a] = grad[src, a]
            B[row] = -curv - (k_fast + gamma) * hdot - gamma * k_fast * hb_i


@jit
def _brake_input(kind, n, vel, dt, hi, out):
    """``BarrierModel.brake``: zero velocity, or against the velocity scaled into the bounds."""
    for j in range(n):
        out[j] = 0.0
    if kind >= DOUBLE_BRAKING:
        peak = 0.0
        for j in range(3):
            peak = max(peak, abs(-vel[j] / dt) / hi[j])
        for j in range(3):
            out[j] = -vel[j] / dt / peak if peak > 1.0 else -vel[j] / dt


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
def _step(kind, n, m, offsets, radius, weights, lo, hi, par, flags, state, u_ref, ang,
                flat, rgs, dims, shape, strides, forigin, inv_h, poly, table,
                pts, dist, grad, hess, rgq, inside, gains, hb, A, B, A2, B2, u_box, u_bk,
                rot, rot1, tmp, omega, pos1, block, w, r1, r2, r3, ws,
                u_out, out_f, out_i, rsrc, rsrc2, seen, u_c):
    """One filter step (SafetyFilter.filter); outcome in out_i = [code, risk group, rows, intervening],
    out_f = [h at the critical point, the barrier there]."""
    delta, alpha_cap, dt, a_brake, a_max, s0, ell = par[0], par[1], par[2], par[3], par[4], par[5], par[6]
    predictive, margins, slack_on, first_order = flags[0], flags[1], flags[2], flags[3]
    out_i[0], out_i[1], out_i[2], out_i[3] = OK, 0, 0, 0
    out_f[0], out_f[1] = 0.0, 0.0
    for j in range(n):
        if not math.isfinite(u_ref[j]):
            out_i[0] = NON_FINITE
            return
    for j in range(3):
        if not math.isfinite(ang[j]):
            out_i[0] = NON_FINITE
            return
    for j in range(15):
        if not math.isfinite(state[j]):
            out_i[0] = HANDBACK  # the numpy path decides what a non-finite state means
            return
    for j in range(n):
        u_box[j] = min(max(u_ref[j], lo[j]), hi[j])
    pos = state[0:3]
    vel = state[12:15]
    for a in range(3):
        for b in range(3):
            rot[a, b] = state[3 + 3 * a + b]
    centred = True
    for i in range(m):
        for a in range(3):
            if offsets[i, a] != 0.0:
                centred = False
    # Barrier points now (rows 0..m-1) and one period ahead under u_box (rows m..2m-1).
    if kind == UNICYCLE:
        th = math.atan2(rot[1, 0], rot[0, 0])
        _yaw_rot(th, rot)
        _rigid_points(pos, rot, offsets, m, pts, 0)
        if predictive:
            v, wz = u_box[0], u_box[1]
            th1 = th + wz * dt
            if abs(wz * dt) < 1e-9:
                dx, dy = v * dt * math.cos(th), v * dt * math.sin(th)
            else:
                dx = v / wz * (math.sin(th1) - math.sin(th))
                dy = -v / wz * (math.cos(th1) - math.cos(th))
            pos1[0], pos1[1], pos1[2] = pos[0] + dx, pos[1] + dy, pos[2]
            _yaw_rot(th1, rot1)
            _rigid_points(pos1, rot1, offsets, m, pts, m)
    elif kind == SINGLE2D or kind == SINGLE3D:
        if kind == SINGLE2D:
            _yaw_rot(math.atan2(rot[1, 0], rot[0, 0]), rot)
            omega[0], omega[1], omega[2] = 0.0, 0.0, ang[2]
        else:
            omega[0], omega[1], omega[2] = ang[0], ang[1], ang[2]
        _rigid_points(pos, rot, offsets, m, pts, 0)
        if predictive:
            # integrate(): p₁ = p + R ∫exp ub, R₁ = R exp(ω dt)
            _so3_integral(omega[0], omega[1], omega[2], dt, tmp)
            for a in range(3):
                s = 0.0
                for b in range(3):
                    rs = 0.0
                    for c in range(3):
                        rs += rot[a, c] * tmp[c, b]
                    s += rs * (u_box[b] if b < n else 0.0)
                pos1[a] = pos[a] + s
            _so3_exp(omega[0] * dt, omega[1] * dt, omega[2] * dt, tmp)
            for a in range(3):
                for b in range(3):
                    s = 0.0
                    for c in range(3):
                        s += rot[a, c] * tmp[c, b]
                    rot1[a, b] = s
            if kind == SINGLE2D:
                _yaw_rot(math.atan2(rot1[1, 0], rot1[0, 0]), rot1)
            _rigid_points(pos1, rot1, offsets, m, pts, m)
    else:
        for i in range(m):
            for a in range(3):
                pts[i, a] = pos[a] + offsets[i, a]
        if predictive:
            for i in range(m):
                for a in range(3):
                    pts[m + i, a] = pos[a] + vel[a] * dt + 0.5 * u_box[a] * dt * dt + offsets[i, a]
    npts = 2 * m if predictive else m
    k = 3 if kind >= DOUBLE_BRAKING else 2
    for i in range(npts):
        for a in range(3):
            if not math.isfinite(pts[i, a]):
                out_i[0] = HANDBACK
                return
        query_point(flat, rgs, dims, shape, strides, forigin, inv_h, poly, k, pts[i], i, dist, grad, hess, rgq, inside,
               block, w, r1, r2, r3)
    nt = table.shape[0]
    for i in range(npts):
        g = min(rgq[i], nt - 1)
        for c in range(4):
            gains[i, c] = table[g, c]
        if first_order:
            gains[i, 0] = min(gains[i, 0], alpha_cap)
    kbest, best = 0, math.inf
    for i in range(m):
        hb[i] = dist[i] - radius[i] - delta
        if margins:
            hb[i] = hb[i] - gains[i, 3]
        val = hb[i]
        if kind == DOUBLE_BRAKING:
            phi, _ = _braking(-(grad[i, 0] * vel[0] + grad[i, 1] * vel[1] + grad[i, 2] * vel[2]), s0, a_brake)
            val = hb[i] - phi
        if val < best or i == 0:
            kbest, best = i, val
    kc = kbest
    h_crit = dist[kc] - radius[kc]
    out_f[0], out_i[1] = h_crit, rgq[kc]
    for i in range(m):
        if not inside[i]:
            out_f[0] = 0.0
            out_i[0] = OUTSIDE_MAP
            return
    for i in range(m):
        _rows(kind, n, m, i, i, rot, omega, offsets, centred, grad, hess, hb[i], gains[i], vel, a_brake, s0, ell,
              A, B, i)
        rsrc[i] = i
    nrows = m
    if predictive:
        for i in range(m):
            j = m + i
            diff = 0.0
            for a in range(3):
                diff = max(diff, abs(grad[j, a] - grad[i, a]))
            same = diff < 0.05 and rgq[j] == rgq[i]
            if inside[j] and not same:
                _rows(kind, n, m, i, j, rot, omega, offsets, centred, grad, hess, hb[i], gains[j], vel, a_brake,
                      s0, ell, A, B, nrows)
                rsrc[nrows] = j
                nrows += 1
    for i in range(nrows):
        ok = math.isfinite(B[i])
        for j in range(n):
            ok = ok and math.isfinite(A[i, j])
        if not ok:
            out_f[0] = 0.0
            out_i[0] = NON_FINITE
            return
    if not math.isfinite(h_crit):
        out_f[0] = 0.0
        out_i[0] = NON_FINITE
        return
    out_i[2] = nrows
    # Rows that hold for every u in the box cannot be active: drop them.
    nlive = 0
    for i in range(nrows):
        s = 0.0
        for j in range(n):
            s += min(A[i, j] * lo[j], A[i, j] * hi[j])
        if B[i] > s + 1e-12:
            for j in range(n):
                A2[nlive, j] = A[i, j]
            B2[nlive] = B[i]
            rsrc2[nlive] = rsrc[i]
            nlive += 1
    status = _active_set(weights, u_ref, A2, B2, nlive, lo, hi, n, u_out, *ws)
    code = OK
    if status == 2:
        out_i[0] = HANDBACK  # the numpy path takes it to OSQP
        return
    if status == 1 and slack_on:
        # SafetyFilter._backup: of the braking input and the maximal braking along each live row's
        # (distinct) gradient, the one whose worst row does best, min_i (a_iᵀu - b_i)/|a_i|.
        _brake_input(kind, n, vel, dt, hi, u_bk)
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
            if kind >= DOUBLE_BRAKING:
                gn = math.sqrt(grad[src, 0] ** 2 + grad[src, 1] ** 2 + grad[src, 2] ** 2)
                if gn > 1e-9:
                    for j in range(3):
                        u_c[j] = a_max * grad[src, j] / gn
                else:
                    _brake_input(kind, n, vel, dt, hi, u_c)
            else:
                for j in range(n):
                    u_c[j] = 0.0
            score = _worst_row(A2, B2, nlive, n, u_c)
            if score > best_score:
                best_score = score
                for j in range(n):
                    u_bk[j] = u_c[j]
        # filter's soft predictive rows: first relax only the rows ahead (rsrc2 ≥ m) that the backup
        # violates, keeping the current rows hard; B keeps the live rows' b meanwhile.
        soft = False
        for i in range(nlive):
            B[i] = B2[i]
            if rsrc2[i] >= m:
                ab = 0.0
                for j in range(n):
                    ab += A2[i, j] * u_bk[j]
                if B2[i] > ab:
                    B2[i] = ab
                    soft = True
        if soft:
            status = _active_set(weights, u_ref, A2, B2, nlive, lo, hi, n, u_out, *ws)
            if status == 2:
                out_i[0] = HANDBACK
                return
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
            status = _active_set(weights, u_ref, A2, B2, nlive, lo, hi, n, u_out, *ws)
            code = SLACK
            if status == 2:
                out_i[0] = HANDBACK
                return
            if status != 0:
                for j in range(n):
                    u_out[j] = u_bk[j]
                status = 0
    if status != 0:
        out_i[0] = INFEASIBLE
        return
    dev = 0.0
    for j in range(n):
        if not math.isfinite(u_out[j]):
            out_i[0] = NON_FINITE
            return
        dev = max(dev, abs(u_out[j] - u_box[j]))
    out_i[0] = code
    out_i[3] = 1 if (code != OK or dev > 1e-6) else 0
    out_f[1] = hb[kc]


@jit
def _take(buf, at, size):
    return buf[at:at + size], at + size


@jit
def step_kernel(ci, cf, inp, flat, rgs, fmi, fmf, table, wf, wi):
    """One filter step over packed arrays (a numba call costs ~0.2 µs per argument: few arguments).

    ci = [model kind, n, m, predictive rows, margins in filter, slack, first order];
    cf = [δ (+ the map margin of the field in hand), α cap, T, a_brake, a_max, braking speed floor s₀,
    braking rate length ℓ, offsets (m×3), radii (m), weights, lo, hi (n each)];
    inp = [position, rotation (row-major), velocity, u_ref (n), angular (3)]; the field as
    ``fields.compiled.kernel_view`` gives it (fmi = [dims, shape, strides], fmf = [origin, 1/h,
    stencil polynomials]); ``table`` the gains per risk group. Outputs: wf[0:2] = [h at the
    critical point, the barrier there], wf[2:2+n] = u; wi[0:4] = [code, risk group, rows,
    intervening]. The rest of wf and wi is scratch, carved here.
    """
    kind, n, m = ci[0], ci[1], ci[2]
    q = 2 * m
    rows = q + 2 * n
    par = cf[0:7]
    offsets, o = _take(cf, 7, 3 * m)
    offsets = offsets.reshape((m, 3))
    radius, o = _take(cf, o, m)
    weights, o = _take(cf, o, n)
    lo, o = _take(cf, o, n)
    hi, o = _take(cf, o, n)
    state, u_ref, ang = inp[0:15], inp[15:15 + n], inp[15 + n:18 + n]
    out_f, u_out = wf[0:2], wf[2:2 + n]
    o = 2 + n
    pts, o = _take(wf, o, 3 * q)
    dist, o = _take(wf, o, q)
    grad, o = _take(wf, o, 3 * q)
    hess, o = _take(wf, o, 9 * q)
    gains, o = _take(wf, o, 4 * q)
    hb, o = _take(wf, o, m)
    A, o = _take(wf, o, q * n)
    B, o = _take(wf, o, q)
    A2, o = _take(wf, o, q * n)
    B2, o = _take(wf, o, q)
    u_box, o = _take(wf, o, n)
    u_bk, o = _take(wf, o, 3)
    rot, o = _take(wf, o, 9)
    rot1, o = _take(wf, o, 9)
    tmp, o = _take(wf, o, 9)
    omega, o = _take(wf, o, 3)
    pos1, o = _take(wf, o, 3)
    block, o = _take(wf, o, 64)
    w, o = _take(wf, o, 36)
    r1, o = _take(wf, o, 48)
    r2, o = _take(wf, o, 36)
    r3, o = _take(wf, o, 27)
    rc, o = _take(wf, o, rows * n)
    rd, o = _take(wf, o, rows)
    norms, o = _take(wf, o, rows)
    gram, o = _take(wf, o, 64)
    aug, o = _take(wf, o, 72)
    z, o = _take(wf, o, n)
    rhs, o = _take(wf, o, 8)
    rr, o = _take(wf, o, 8)
    step, o = _take(wf, o, n)
    lam, o = _take(wf, o, 8)
    marks, o = _take(wf, o, 2 * n)
    sw, o = _take(wf, o, n)
    u_c, o = _take(wf, o, 3)
    out_i = wi[0:4]
    rgq, o = _take(wi, 4, q)
    inside, o = _take(wi, o, q)
    active, o = _take(wi, o, 8)
    rsrc, o = _take(wi, o, q)
    rsrc2, o = _take(wi, o, q)
    seen, o = _take(wi, o, q)
    _step(kind, n, m, offsets, radius, weights, lo, hi, par, ci[3:7], state, u_ref, ang,
          flat, rgs, fmi[0], fmi[1:4], fmi[4:7], fmf[0:3], fmf[3], fmf[4:52].reshape((3, 4, 4)), table,
          pts.reshape((q, 3)), dist, grad.reshape((q, 3)), hess.reshape((q, 3, 3)), rgq, inside,
          gains.reshape((q, 4)), hb, A.reshape((q, n)), B, A2.reshape((q, n)), B2, u_box, u_bk,
          rot.reshape((3, 3)), rot1.reshape((3, 3)), tmp.reshape((3, 3)), omega, pos1, block.reshape((4, 4, 4)),
          w.reshape((3, 3, 4)), r1.reshape((4, 4, 3)), r2.reshape((4, 3, 3)), r3.reshape((3, 3, 3)),
          (rc.reshape((rows, n)), rd, norms, gram.reshape((8, 8)), aug.reshape((8, 9)), z, rhs, rr, step, lam,
           marks, sw, active),
          u_out, out_f, out_i, rsrc, rsrc2, seen, u_c)


def workspace_sizes(m: int, n: int) -> tuple[int, int]:
    """Lengths of :func:`step_kernel`'s float and int workspaces (its carving, summed)."""
    q, rows = 2 * m, 2 * m + 2 * n
    floats = (2 + n + 3 * q + q + 3 * q + 9 * q + 4 * q + m + q * n + q + q * n + q + n + 3 + 9 * 3 + 3 + 3
              + 64 + 36 + 48 + 36 + 27 + rows * n + rows + rows + 64 + 72 + n + 8 + 8 + n + 8 + 2 * n + n + 3)
    return floats, 4 + 2 * q + 8 + 3 * q


# --------------------------------------------------------------------------- the Python side


class CompiledStep:
    """Preallocated buffers and constants of one filter's compiled step.

    ``run`` fills the state buffer, calls :func:`step_kernel` once and leaves the outcome in
    ``u``, ``out_f`` and ``out_i``; :meth:`SafetyFilter.filter <.filter.SafetyFilter.filter>`
    turns it into a ``FilterResult``. Built (and the kernel compiled or loaded from numba's
    cache) once per filter: :meth:`warm_up` runs it on a small grid.
    """

    def __init__(self, model, kind: int, delta: float, alpha_cap: float, dt: float, predictive: bool,
                 margins_in_filter: bool, slack: bool, map_margin_voxels: float = 0.0):
        if not HAVE_NUMBA:
            raise RuntimeError("the compiled filter step needs numba (pip install '.[robot]')")
        m, n = model.m, model.n
        self.kind, self.m, self.n = kind, m, n
        a_max = float(getattr(model, "a_max", 0.0))
        a_brake = float(getattr(model, "a_brake", 1.0))
        s0 = float(getattr(model, "speed_floor", 1.0))
        ell = float(getattr(model, "rate_length", math.inf))
        # δ of the kernel = δ + map_margin_voxels · the voxel size of the field in hand (``prepare``).
        self.delta, self.map_margin_voxels = delta, map_margin_voxels
        cap = alpha_cap if math.isfinite(alpha_cap) else 1e300
        self.ci = np.array([kind, n, m, predictive, margins_in_filter, slack, kind < DOUBLE_BRAKING], np.int64)
        self.cf = np.concatenate([[delta, cap, dt, a_brake, a_max, s0, ell],
                                  np.asarray(model.offsets, np.float64).ravel(),
                                  model.radius, model.weights, model.lo, model.hi]).astype(np.float64)
        self.inp = np.zeros(18 + n)
        floats, ints = workspace_sizes(m, n)
        self.wf, self.wi = np.zeros(floats), np.zeros(ints, np.int64)
        # Views of the outputs (step_kernel's docstring).
        self.out_f, self.u, self.out_i = self.wf[0:2], self.wf[2:2 + n], self.wi[0:4]
        self._field: tuple | None = None

    def prepare(self, field: EsdfField) -> tuple:
        """The kernel's view of a field (``fields.compiled.kernel_view``), kept per map."""
        if self._field is not None and self._field[0] is field:
            return self._field[1]
        view = kernel_view(field)
        self._field = (field, view)
        self.cf[0] = self.delta + self.map_margin_voxels * field.voxel_size
        return view

    def run(self, position: np.ndarray, rotation: np.ndarray, velocity: np.ndarray, u_ref: np.ndarray,
            ang: np.ndarray, field: EsdfField, table: np.ndarray) -> None:
        inp, n = self.inp, self.n
        inp[0:3] = position
        inp[3:12] = rotation.reshape(9)
        inp[12:15] = velocity
        inp[15:15 + n] = u_ref
        inp[15 + n:18 + n] = ang
        flat, rgs, fmi, fmf = self.prepare(field)
        step_kernel(self.ci, self.cf, inp, flat, rgs, fmi, fmf, table, self.wf, self.wi)

    def warm_up(self, table: np.ndarray) -> None:
        """Compile (or load from the on-disk cache) with the argument types of the control loop."""
        for planar in (True, False):
            shape = (4, 4, 1) if planar else (4, 4, 4)
            field = EsdfField(np.ones(shape, np.float32), (0.0, 0.0, 0.0), 0.1, interpolation="bspline_smooth")
            self.run(np.array([0.15, 0.15, 0.0 if planar else 0.15]), np.eye(3), np.zeros(3), np.zeros(self.n),
                     np.zeros(3), field, table)
        self._field = None


def model_kind(model) -> int:
    """The kernel's model kind of a barrier model (``barriers``)."""
    name = model.name
    if name == "unicycle":
        return UNICYCLE
    if name in ("single2d", "single3d"):
        return SINGLE2D if name == "single2d" else SINGLE3D
    return DOUBLE_HOCBF if model.kind == "hocbf" else DOUBLE_BRAKING
