"""The exact active-set path against brute-force enumeration and against OSQP."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from oracles.qp import OsqpSolver, QPResult
from riskfield.services.safety_filter.compiled import ExactQP


class ActiveSetSolver:
    """The filter's compiled QP (``compiled.ExactQP``) behind the oracle solvers' interface."""

    def solve(self, w, r, A, b, lo, hi) -> QPResult:
        status, u = ExactQP(w, lo, hi, max(len(b), 1)).solve(r, np.asarray(A, np.float64).reshape(len(b), len(r)), b)
        return QPResult(u, status, 0, "active_set")  # type: ignore[arg-type]


def brute_force(w, r, A, b, lo, hi):
    """Minimum over every active set of ≤ n rows: the KKT point that is feasible (or None)."""
    n = len(r)
    sw = np.sqrt(w)
    C = np.concatenate([A / sw, np.eye(n), -np.eye(n)])
    d = np.concatenate([b - A @ r, sw * (lo - r), -sw * (hi - r)])
    best = None
    for q in range(n + 1):
        for S in itertools.combinations(range(len(d)), q):
            N = C[list(S)]
            if q:
                M = N @ N.T
                if abs(np.linalg.det(M)) < 1e-12:
                    continue
                z = N.T @ np.linalg.solve(M, d[list(S)])
            else:
                z = np.zeros(n)
            if (C @ z - d >= -1e-9).all() and (best is None or z @ z < best @ best):
                best = z
    return None if best is None else r + best / sw


def problems(max_rows=3):
    @st.composite
    def build(draw):
        n = draw(st.integers(1, 3))
        m = draw(st.integers(0, max_rows))
        seed = draw(st.integers(0, 2**31))
        rng = np.random.default_rng(seed)
        w = rng.uniform(0.1, 5, n)
        r = rng.normal(0, 2, n)
        A = rng.normal(0, 1, (m, n))
        if m and draw(st.booleans()):
            A[:, rng.integers(0, n)] = 0.0  # a row that cannot use one input
        b = rng.normal(0, 1, m)
        lo, hi = -rng.uniform(0.1, 2, n), rng.uniform(0.1, 2, n)
        return w, r, A, b, lo, hi
    return build()


_OSQP: dict[tuple[int, int], OsqpSolver] = {}


def osqp_for(n, m):
    if (n, m) not in _OSQP:
        _OSQP[(n, m)] = OsqpSolver(n, m)
    return _OSQP[(n, m)]


@settings(max_examples=400, deadline=None)
@given(problems())
def test_active_set_is_exact_and_agrees_with_osqp(problem):
    w, r, A, b, lo, hi = problem
    got = ActiveSetSolver().solve(w, r, A, b, lo, hi)
    want = brute_force(w, r, A, b, lo, hi)
    osqp = osqp_for(len(r), len(b)).solve(w, r, A, b, lo, hi)  # reused: updates + warm start
    if want is None:
        assert got.status == "infeasible"
        assert osqp.status in ("infeasible", "failed")
        return
    assert got.status == "solved"
    np.testing.assert_allclose(got.u, want, atol=1e-7)
    assert np.all(got.u >= lo) and np.all(got.u <= hi)
    if len(b):
        assert (A @ got.u - b).min() >= -1e-6 * (1 + np.abs(b).max())
    assert osqp.status == "solved"
    np.testing.assert_allclose(osqp.u, want, atol=2e-4)


def test_admissible_reference_passes_unchanged():
    r = np.array([0.3, -0.2])
    res = ActiveSetSolver().solve(np.ones(2), r, np.array([[1.0, 0.0]]), np.array([-1.0]), -np.ones(2), np.ones(2))
    assert res.ok
    np.testing.assert_array_equal(res.u, r)


def test_one_row_projection_has_the_closed_form():
    # min (v - 1)² + λ (ω - 0)² s.t. v + ω ≥ ... the unconstrained projection onto a·u = b.
    w = np.array([1.0, 4.0])
    r = np.array([1.0, 0.0])
    a = np.array([[-1.0, -1.0]])
    b = np.array([-0.5])  # v + ω ≤ 0.5
    res = ActiveSetSolver().solve(w, r, a, b, -np.full(2, 10.0), np.full(2, 10.0))
    mu = (b[0] - a[0] @ r) / (a[0] @ (a[0] / w))
    np.testing.assert_allclose(res.u, r + mu * a[0] / w, atol=1e-12)


def test_infeasible_rows_are_reported_by_both_solvers():
    # v ≥ 2 with |v| ≤ 1: no solution.
    args = (np.ones(2), np.zeros(2), np.array([[1.0, 0.0]]), np.array([2.0]), -np.ones(2), np.ones(2))
    assert ActiveSetSolver().solve(*args).status == "infeasible"
    assert OsqpSolver(2, 1).solve(*args).status == "infeasible"
    # Two rows contradicting each other inside generous bounds.
    args2 = (np.ones(2), np.zeros(2), np.array([[1.0, 1.0], [-1.0, -1.0]]), np.array([1.0, 0.0]),
             -np.full(2, 5.0), np.full(2, 5.0))
    assert ActiveSetSolver().solve(*args2).status == "infeasible"
    assert OsqpSolver(2, 2).solve(*args2).status == "infeasible"


def test_osqp_that_cannot_converge_reports_failure_not_a_guess():
    solver = OsqpSolver(2, 1, max_iter=1)
    res = solver.solve(np.ones(2), np.array([1.0, 0.5]), np.array([[-1.0, -0.2]]), np.array([-0.1]),
                       -np.ones(2), np.ones(2))
    assert res.status == "failed"
    assert np.isfinite(res.u).all()


def test_osqp_rejects_a_problem_of_another_size():
    with pytest.raises(ValueError):
        OsqpSolver(2, 1).solve(np.ones(2), np.zeros(2), np.zeros((2, 2)), np.zeros(2), -np.ones(2), np.ones(2))


def test_infinite_bounds_are_allowed_by_the_general_path():
    inf = np.full(3, np.inf)
    A = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    res = ActiveSetSolver().solve(np.ones(3), np.zeros(3), A, np.array([1.0, 2.0]), -inf, inf)
    np.testing.assert_allclose(res.u, [1.0, 2.0, 0.0], atol=1e-12)


def test_padding_rows_that_always_hold_do_not_disable_the_accuracy_check():
    # Row 2 is padding (b = -inf). A loose OSQP answer violates row 1 and must be refused.
    args = (np.ones(2), np.array([1.0, 0.5]), np.array([[-1.0, -0.3], [0.0, 0.0]]), np.array([-0.2, -np.inf]),
            -np.ones(2), np.ones(2))
    loose = OsqpSolver(2, 2, eps=0.5, max_iter=2000).solve(*args)
    assert loose.status == "failed"
    exact = ActiveSetSolver().solve(*args)
    good = OsqpSolver(2, 2).solve(*args)
    assert exact.ok and good.ok
    np.testing.assert_allclose(good.u, exact.u, atol=1e-4)


@settings(max_examples=150, deadline=None)
@given(problems(max_rows=9))
def test_whole_body_row_counts_agree_with_brute_force_and_osqp(problem):
    """Up to 9 rows: the look-ahead point, three body discs and their predictive rows, plus one."""
    w, r, A, b, lo, hi = problem
    got = ActiveSetSolver().solve(w, r, A, b, lo, hi)
    want = brute_force(w, r, A, b, lo, hi)
    osqp = osqp_for(len(r), len(b)).solve(w, r, A, b, lo, hi)
    if want is None:
        assert got.status == "infeasible" and osqp.status in ("infeasible", "failed")
        return
    assert got.status == "solved" and osqp.status == "solved"
    np.testing.assert_allclose(got.u, want, atol=1e-7)
    np.testing.assert_allclose(osqp.u, want, atol=2e-4)


@settings(max_examples=150, deadline=None)
@given(problems(max_rows=9), st.integers(0, 2**31))
def test_slack_relaxed_qp_is_feasible_and_at_least_as_good_as_the_backup(problem, seed):
    """The filter's relaxation A u ≥ min(b, A u_bk) for a backup u_bk in the box: always feasible,
    every row at least as satisfied as under the backup, and both solvers agree on it."""
    w, r, A, b, lo, hi = problem
    u_bk = np.random.default_rng(seed).uniform(lo, hi)
    relaxed = np.minimum(b, A @ u_bk)
    got = ActiveSetSolver().solve(w, r, A, relaxed, lo, hi)
    osqp = osqp_for(len(r), len(b)).solve(w, r, A, relaxed, lo, hi)
    assert got.status == "solved" and osqp.status == "solved"
    want = brute_force(w, r, A, relaxed, lo, hi)
    np.testing.assert_allclose(got.u, want, atol=1e-7)
    np.testing.assert_allclose(osqp.u, want, atol=2e-4)
    if len(b):
        assert np.all(A @ got.u >= np.minimum(b, A @ u_bk) - 1e-6 * (1 + np.abs(b).max()))
