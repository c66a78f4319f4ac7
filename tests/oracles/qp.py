"""The safety filter's quadratic program in numpy and OSQP: the oracles of its compiled QP
(``services/safety_filter/compiled.py``).

Every barrier model leads to the same small problem in its input u ∈ Rⁿ (n ≤ 3):

    minimise   ½ (u - u_ref)ᵀ W (u - u_ref)        W = diag(w), w > 0   (λv, λω of the paper)
    subject to A u ≥ b                              one row per barrier point
               lo ≤ u ≤ hi                          input bounds

Two solvers return the same answer:

* :class:`ActiveSetSolver` — exact, for tiny problems. With z = W^½ (u - u_ref) the problem is
  the projection of the origin onto a polytope {z : C z ≥ d} (general rows and bound rows
  alike), solved by the Goldfarb–Idnani dual active-set method: start at the unconstrained
  optimum z = 0, repeatedly add the most violated row and take the step that keeps the
  current rows active and their multipliers non-negative (dropping a row whose multiplier
  would turn negative). Each iteration solves a ≤ 3×3 system; it terminates in a few
  iterations with the exact optimum, or proves infeasibility when a violated row can be
  satisfied neither by a primal step nor by releasing an active row.
* :class:`OsqpSolver` — OSQP, set up once with a fixed sparsity pattern for (n, m) and then
  only updated (values of P, q, A, l, u), warm started, silent, with solution polishing so
  that active rows hold to solver precision.

Both report ``infeasible`` (no u satisfies the rows within the bounds) or ``failed``
(numerical trouble) instead of returning a doubtful u; the caller then brakes.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from typing import Literal

import numpy as np
import osqp
import scipy.sparse as sp

Status = Literal["solved", "infeasible", "failed"]

#: Rows of A u ≥ b may be violated by at most this much (absolute) in an accepted solution.
FEASIBILITY_TOL = 1e-6


@dataclass(frozen=True)
class QPResult:
    u: np.ndarray
    status: Status
    iterations: int
    solver: str

    @property
    def ok(self) -> bool:
        return self.status == "solved"


class ActiveSetSolver:
    """Exact dual active-set solution of the box-and-rows QP for n ≤ 3 variables.

    Written with plain Python floats: for vectors of length ≤ 3 that is several times faster
    than numpy, whose per-call overhead would dominate.
    """

    name = "active_set"

    def __init__(self, max_iter: int = 50, tol: float = 1e-12):
        self.max_iter = max_iter
        self.tol = tol

    def solve(self, w: np.ndarray, u_ref: np.ndarray, A: np.ndarray, b: np.ndarray,
              lo: np.ndarray, hi: np.ndarray) -> QPResult:
        n = len(u_ref)
        if A.shape[0] == 1:
            return self._one_row(w, u_ref, A[0], float(b[0]), lo, hi)
        r, al, bl = u_ref.tolist(), A.tolist(), b.tolist()
        sw = [math.sqrt(x) for x in w.tolist()]
        # Rows c·z ≥ d in the scaled variable z = sqrt(w) (u - u_ref); bound rows are ±e_j.
        rows: list[tuple[list[float], float]] = []
        for a, bi in zip(al, bl, strict=True):
            rows.append(([a[j] / sw[j] for j in range(n)], bi - _dot(a, r)))
        for j, (lj, hj) in enumerate(zip(lo.tolist(), hi.tolist(), strict=True)):
            if lj > -math.inf:
                rows.append(([1.0 if k == j else 0.0 for k in range(n)], sw[j] * (lj - r[j])))
            if hj < math.inf:
                rows.append(([-1.0 if k == j else 0.0 for k in range(n)], -sw[j] * (hj - r[j])))
        if max((d for _, d in rows), default=-math.inf) <= FEASIBILITY_TOL:
            return QPResult(u_ref.copy(), "solved", 0, self.name)  # the reference is admissible
        status, z, it = self._dual_active_set(rows, n)
        if status != "solved":
            return QPResult(np.zeros(n), status, it, self.name)
        u = np.minimum(np.maximum(u_ref + np.array(z) / np.array(sw), lo), hi)
        scale = 1.0 + max((abs(x) for x in bl if math.isfinite(x)), default=0.0)
        if al and (A @ u - b).min() < -FEASIBILITY_TOL * scale:
            return QPResult(np.zeros(n), "failed", it, self.name)
        return QPResult(u, "solved", it, self.name)

    def _one_row(self, w: np.ndarray, u_ref: np.ndarray, a: np.ndarray, b: float,
                 lo: np.ndarray, hi: np.ndarray) -> QPResult:
        """One row aᵀu ≥ b: exact search along the dual ray.

        For a multiplier μ ≥ 0 the box-constrained minimiser of the Lagrangian is
        u(μ) = clip(u_ref + μ a / w, lo, hi), and g(μ) = aᵀu(μ) is non-decreasing and piecewise
        linear (each component moves with slope a_j²/w_j until it reaches a bound). The optimum
        is u(0) when g(0) ≥ b, else u(μ*) at the smallest μ* with g(μ*) = b; when g never reaches
        b the problem is infeasible.
        """
        n = len(u_ref)
        r, al, lol, hil = u_ref.tolist(), a.tolist(), lo.tolist(), hi.tolist()
        sl = [al[j] / w_j for j, w_j in enumerate(w.tolist())]
        u0 = [min(max(r[j], lol[j]), hil[j]) for j in range(n)]
        g = _dot(al, u0)
        if g >= b - FEASIBILITY_TOL * (1.0 + abs(b)):
            return QPResult(np.array(u0), "solved", 0, self.name)
        # Breakpoints: the μ at which a component enters or leaves its interval.
        marks = sorted({m for j in range(n) if sl[j] != 0.0
                        for m in ((lol[j] - r[j]) / sl[j], (hil[j] - r[j]) / sl[j]) if 0.0 < m < math.inf})
        mu_prev, g_prev = 0.0, g
        for k, mu in enumerate([*marks, math.inf]):
            # Slope of g on (mu_prev, mu): components strictly inside their interval there.
            # Past the last breakpoint any μ will do; 2μ + 1 stays clear of it in floating point too
            # (μ + 1 rounds back to μ for μ ≳ 1e16, from a near-zero coefficient of a).
            mid = 2.0 * mu_prev + 1.0 if mu == math.inf else 0.5 * (mu_prev + mu)
            slope = sum(al[j] * sl[j] for j in range(n) if lol[j] < r[j] + mid * sl[j] < hil[j])
            g_next = g_prev + slope * (mu - mu_prev) if mu != math.inf else (math.inf if slope > 0 else g_prev)
            if g_next >= b:
                mu_star = mu_prev + (b - g_prev) / slope
                u = [min(max(r[j] + mu_star * sl[j], lol[j]), hil[j]) for j in range(n)]
                if _dot(al, u) < b - FEASIBILITY_TOL * (1.0 + abs(b)):
                    break  # rounding on a breakpoint counted a saturated component: g never gets there
                return QPResult(np.array(u), "solved", k + 1, self.name)
            mu_prev, g_prev = mu, g_next
        return QPResult(np.zeros(n), "infeasible", len(marks) + 1, self.name)

    def _dual_active_set(self, rows: list[tuple[list[float], float]], n: int) -> tuple[Status, list[float], int]:
        tol = self.tol
        norms = [max(math.sqrt(_dot(c, c)), tol) for c, _ in rows]
        z = [0.0] * n
        active: list[int] = []
        lam: list[float] = []
        it = 0
        while it < self.max_iter:
            # The most violated row, measured as a distance (rows have different scales).
            p, worst = -1, -FEASIBILITY_TOL
            for i, (c, d) in enumerate(rows):
                s = (_dot(c, z) - d) / norms[i]
                if s < worst:
                    p, worst = i, s
            if p < 0:
                return "solved", z, it
            n_p, d_p = rows[p]
            lam_p = 0.0
            while it < self.max_iter:
                it += 1
                if active:
                    nrows = [rows[i][0] for i in active]
                    gram = [[_dot(a, c) for c in nrows] for a in nrows]
                    rhs = [_dot(a, n_p) for a in nrows]
                    rr = _solve_small(gram, rhs)
                    if rr is None:
                        return "failed", z, it
                    # n_p projected onto the null space of the active rows: the primal direction.
                    step = [n_p[k] - sum(rr[i] * nrows[i][k] for i in range(len(nrows))) for k in range(n)]
                else:
                    rr = []
                    step = n_p
                t1, drop = math.inf, -1  # longest dual step keeping the active multipliers ≥ 0
                for j, rj in enumerate(rr):
                    if rj > 1e-12 and lam[j] / rj < t1:
                        t1, drop = lam[j] / rj, j
                zz = _dot(step, step)
                slack = _dot(n_p, z) - d_p  # < 0 while row p is violated
                t2 = -slack / zz if zz > 1e-12 * norms[p] ** 2 else math.inf
                if t1 == math.inf and t2 == math.inf:
                    return "infeasible", z, it
                t = min(t1, t2)
                if t2 != math.inf:
                    z = [z[k] + t * step[k] for k in range(n)]
                for j in range(len(lam)):
                    lam[j] -= t * rr[j]
                lam_p += t
                if t2 <= t1:  # full step: row p becomes active
                    active.append(p)
                    lam.append(lam_p)
                    break
                del active[drop], lam[drop]  # partial step: release the row whose multiplier reached 0
        return "failed", z, it


def _dot(a: list[float], b: list[float]) -> float:
    return sum(map(operator.mul, a, b))


def _solve_small(m: list[list[float]], v: list[float]) -> list[float] | None:
    """Gaussian elimination with partial pivoting for a q×q system (q ≤ 3); None if singular."""
    q = len(v)
    a = [[*row, v[i]] for i, row in enumerate(m)]
    scale = max(max(abs(x) for x in row) for row in m) or 1.0
    for col in range(q):
        piv = max(range(col, q), key=lambda i: abs(a[i][col]))
        if abs(a[piv][col]) <= 1e-12 * scale:
            return None
        a[col], a[piv] = a[piv], a[col]
        for i in range(col + 1, q):
            f = a[i][col] / a[col][col]
            for k in range(col, q + 1):
                a[i][k] -= f * a[col][k]
    x = [0.0] * q
    for i in range(q - 1, -1, -1):
        x[i] = (a[i][q] - sum(a[i][k] * x[k] for k in range(i + 1, q))) / a[i][i]
    return x


class OsqpSolver:
    """OSQP on the same problem, set up once per (n, m) and updated in place each step."""

    name = "osqp"

    def __init__(self, n: int, m: int, eps: float = 1e-7, max_iter: int = 4000, polish: bool = False):
        self.n, self.m = n, m
        # Constraint matrix [A; I] in CSC with every entry of A stored, so updates keep the pattern.
        rows = np.concatenate([np.concatenate([np.arange(m), [m + j]]) for j in range(n)])
        indptr = np.arange(0, (m + 1) * n + 1, m + 1)
        self._ax = np.ones((m + 1, n))
        a = sp.csc_matrix((self._ax.T.ravel(), rows, indptr), shape=(m + n, n))
        p = sp.csc_matrix((np.ones(n), np.arange(n), np.arange(n + 1)), shape=(n, n))
        self._l = np.full(m + n, -np.inf)
        self._u = np.full(m + n, np.inf)
        self._prob = osqp.OSQP()
        self._prob.setup(p, np.zeros(n), a, np.zeros(m + n), np.full(m + n, np.inf), verbose=False,
                         warm_starting=True, polishing=polish, eps_abs=eps, eps_rel=eps, max_iter=max_iter,
                         polish_refine_iter=5)
        self._ok = {osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE}
        self._infeasible = {osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE,
                            osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE_INACCURATE}

    def solve(self, w: np.ndarray, u_ref: np.ndarray, A: np.ndarray, b: np.ndarray,
              lo: np.ndarray, hi: np.ndarray) -> QPResult:
        n, m = self.n, self.m
        if A.shape != (m, n):
            raise ValueError(f"this solver was set up for {m}×{n} rows, got {A.shape}")
        self._ax[:m] = A
        self._l[:m], self._l[m:] = b, lo
        self._u[m:] = hi
        self._prob.update(Px=w, q=-w * u_ref, Ax=self._ax.T.ravel(), l=self._l, u=self._u)
        res = self._prob.solve(raise_error=False)
        status = res.info.status_val
        it = int(res.info.iter)
        if status in self._infeasible:
            return QPResult(np.zeros(n), "infeasible", it, self.name)
        if status not in self._ok or res.x is None or not np.isfinite(res.x).all():
            return QPResult(np.zeros(n), "failed", it, self.name)
        u = np.minimum(np.maximum(np.asarray(res.x, dtype=np.float64), lo), hi)
        # OSQP is approximate: accept only a solution whose rows hold (up to a small tolerance).
        live = np.isfinite(b)
        if live.any() and (A[live] @ u - b[live]).min() < -1e-5 * (1.0 + np.abs(b[live]).max()):
            return QPResult(np.zeros(n), "failed", it, self.name)
        return QPResult(u, "solved", it, self.name)
