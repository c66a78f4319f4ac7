"""The safety filter's step in numpy, as a test oracle of the compiled step
(``services/safety_filter/compiled.py``): the same points, rows, row dropping, yielding, soft
predictive rows and slack relaxation, written with numpy arrays and solved by :mod:`oracles.qp`
(the active-set QP in plain Python, or OSQP)."""

from __future__ import annotations

import math
import time

import numpy as np

from oracles.qp import ActiveSetSolver, OsqpSolver, QPResult
from riskfield.services.fields import DistanceField, FieldSample
from riskfield.services.safety_filter import compiled
from riskfield.services.safety_filter import model as mdl
from riskfield.services.safety_filter.filter import FilterResult, SafetyFilter
from riskfield.services.safety_filter.model import YIELD
from riskfield.services.safety_filter.state import FilterState

_ZERO3 = np.zeros(3)


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float64)


def _rows_of(s: FieldSample, rows: slice) -> FieldSample:
    return FieldSample(s.distance[rows], s.gradient[rows], None if s.hessian is None else s.hessian[rows],
                       s.risk_group[rows], s.inside[rows])


class ReferenceFilter:
    """``filt``'s step (its model, configuration, δ and gains) in numpy; ``solver`` "active_set" or
    "osqp" solves every QP of the step."""

    def __init__(self, filt: SafetyFilter, solver: str = "active_set"):
        self.filt, self.model, self.config, self.delta = filt, filt.model, filt.config, filt.delta
        self._first_order = not self.model.needs_hessian
        self._alpha_cap = filt._alpha_cap
        self.max_object_rows = self.config.max_object_rows if self.config.object_motion else 0
        self.rows_max = self.model.m * (2 if self.config.predictive_rows else 1) + 2 * self.max_object_rows
        self._use_active_set = solver == "active_set"
        self._active_set = ActiveSetSolver()
        self._osqp: OsqpSolver | None = None

    @property
    def gains(self):
        return self.filt.gains

    def field_for(self, field: DistanceField) -> DistanceField:
        return self.filt.field_for(field)

    def osqp(self) -> OsqpSolver:
        if self._osqp is None:
            self._osqp = OsqpSolver(self.model.n, self.rows_max)
        return self._osqp

    def object_rows(self, state: FilterState, u_box: np.ndarray, pts: np.ndarray, objects: np.ndarray,
                    table: np.ndarray, delta: float, ang: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A, b, gradients) of the moving objects on a collision course (``model.object_course``),
        the ``max_object_rows`` soonest first, each with its own two rows (``model.object_sample``:
        its body, then the capsule it sweeps in ``object_sweep_s``)."""
        model, cfg = self.model, self.config
        rot = model.rotation(state)
        v_ref = np.empty(3)
        mdl.reference_velocity(model.di, model.df, model.dl, rot, _f64(state.velocity), _f64(u_box), v_ref)
        when = []
        for k, obj in enumerate(objects):
            g = table[min(int(obj[mdl.OBJ_GROUP]), table.shape[0] - 1)]
            t = mdl.object_course(model.desc, pts, v_ref, _f64(state.velocity), obj, float(g[mdl.MARGIN]),
                                  delta, cfg.collision_horizon_s, cfg.a_max)
            if math.isfinite(t):
                when.append((t, k))
        when = sorted(when)[:self.max_object_rows]
        rows = 2 * len(when)  # per object: its body, then the capsule it sweeps (model.object_sample)
        a, b, grads = np.empty((rows, model.n)), np.empty(rows), np.empty((rows, 3))
        hess, wobj = np.empty((3, 3)), np.empty(3)
        for r, (_, k) in enumerate(when):
            obj = objects[k]
            g = table[min(int(obj[mdl.OBJ_GROUP]), table.shape[0] - 1)].copy()
            if self._first_order:
                g[0] = min(g[0], self._alpha_cap)
            for part in range(2):
                q = 2 * r + part
                i, hb = mdl.object_sample(model.desc, pts, obj, g, delta, cfg.object_sweep_s * part, grads[q],
                                          hess, wobj)
                b[q] = mdl.point_row(model.desc, (rot, ang, _f64(state.velocity)), i, grads[q], hess,
                                     hb, g, wobj, a[q])
        return a, b, grads

    def filter(self, state: FilterState, u_ref: np.ndarray, field: DistanceField,
               angular: np.ndarray | None = None, objects: np.ndarray | None = None) -> FilterResult:
        t0 = time.perf_counter()
        if objects is not None and (not self.config.object_motion or len(objects) == 0):
            objects = None
        if objects is not None:
            objects = np.ascontiguousarray(objects[:compiled.MAX_OBJECTS], np.float64)
        model = self.model
        ang = _ZERO3 if angular is None else np.asarray(angular, np.float64)
        u_ref = np.asarray(u_ref, np.float64)
        if u_ref.shape != (model.n,) or not all(map(math.isfinite, (*u_ref.tolist(), *ang.tolist()))):
            return self._brake(state, u_ref, "non_finite", t0)
        u_box = np.minimum(np.maximum(u_ref, model.lo), model.hi)
        pts = model.points(state)
        m = pts.shape[0]
        if self.config.predictive_rows:
            # Where the barrier points would be one period later under the (bounded) reference.
            pts = np.concatenate([pts, model.predicted_points(state, u_box, self.config.dt, ang)])
        field = self.filt.field_for(field)
        both = field.query(pts, hessian=model.needs_hessian)
        sample = _rows_of(both, slice(0, m))
        clearance = sample.distance - model.radius
        gains = self.filt.gains_at(field, both)
        if self._first_order:
            gains = gains.copy()
            gains[:, 0] = np.minimum(gains[:, 0], self._alpha_cap)
        hb = np.empty(m)
        delta = self.delta + self.config.map_margin_voxels * getattr(field, "voxel_size", 0.0)
        k = mdl.barriers(model.desc, _f64(sample.distance), _f64(sample.gradient),
                         _f64(state.velocity), _f64(gains[:m]), delta, self.config.margins_in_filter, hb, _ZERO3)
        h_crit, rg = float(clearance[k]), int(sample.risk_group[k])
        if not sample.inside.all():
            return self._brake(state, u_ref, "outside_map", t0, 0.0, rg)
        a, b = model.rows(state, sample, hb, gains[:m], ang)
        gradients = sample.gradient  # one per row: the candidate backup directions
        yields = gains[:m, YIELD] > 0
        ahead = np.zeros(m, bool)  # the predictive rows
        if self.config.predictive_rows:
            # The same CBF row with the gradient (and group) found at the predicted point: where the
            # nearest obstacle changes within one period (the ridge between two obstacles, where the
            # distance field has a kink) this row constrains the approach to the obstacle about to
            # become nearest, which the current gradient cannot see. h stays the current one (the
            # smaller), so the row is at least as strict as that obstacle's own CBF row and u = 0
            # always satisfies it. Rows whose gradient and group match the current ones are dropped.
            ahead_s = _rows_of(both, slice(m, 2 * m))
            same = (np.abs(ahead_s.gradient - sample.gradient).max(axis=1) < 0.05) & (
                ahead_s.risk_group == sample.risk_group)
            keep = ahead_s.inside & ~same
            if keep.any():
                gradients = np.concatenate([gradients, ahead_s.gradient[keep]])
                a2, b2 = model.rows(state, ahead_s, hb, gains[m:], ang)
                a, b = np.concatenate([a, a2[keep]]), np.concatenate([b, b2[keep]])
                yields = np.concatenate([yields, gains[m:][keep, YIELD] > 0])
                ahead = np.concatenate([ahead, np.ones(int(keep.sum()), bool)])
        n_obj = 0
        if objects is not None:
            ao, bo, go = self.object_rows(state, u_box, _f64(pts[:m]), objects,
                                          self.filt.gains.for_groups(field.groups), delta, ang)
            n_obj = len(bo) // 2
            a, b, gradients = np.concatenate([a, ao]), np.concatenate([b, bo]), np.concatenate([gradients, go])
            yields = np.concatenate([yields, np.ones(len(bo), bool)])
            ahead = np.concatenate([ahead, np.zeros(len(bo), bool)])
        if not (np.isfinite(a).all() and np.isfinite(b).all() and math.isfinite(h_crit)):
            return self._brake(state, u_ref, "non_finite", t0, 0.0, rg)
        yielding = False
        if yields.any():
            u_stop = model.brake(state)
            for r in np.flatnonzero(yields):
                b[r], clipped = mdl.yield_clip(model.di, a[r], float(b[r]), u_stop)
                yielding = yielding or clipped
        n_rows = a.shape[0]
        # Rows that hold for every u in the box cannot be active: drop them.
        live = b > np.minimum(a * model.lo, a * model.hi).sum(axis=1) + 1e-12
        if not live.all():
            a, b = a[live], b[live]
        lo, hi = np.empty(model.n), np.empty(model.n)
        boxed = bool(yields[live].any()) and mdl.yield_box(model.di, model.df, model.dl, u_ref, lo, hi)
        res = self._solve(a, b, u_ref, lo, hi) if boxed else self._solve(a, b, u_ref)
        if res.status == "infeasible" and boxed:
            # The static rows ask more than slowing (recovery from inside a static margin): the
            # full box, the yielding rows still clipped.
            res = self._solve(a, b, u_ref)
        fallback = None
        if res.status == "infeasible" and self.config.slack:
            u_bk = self._backup(state, a, b, gradients[live])
            ab = a @ u_bk
            soft = ahead[live] & (b > ab)
            if soft.any():
                # Soft predictive rows (module docstring): the current rows alone certify the barrier.
                res = self._solve(a, np.where(soft, ab, b), u_ref)
            # A violated row without a direction (zero gradient: deep inside a solid region) cannot
            # tell a better input from a worse one: brake (fallback "infeasible").
            blind = (b > ab) & (np.abs(a).max(axis=1) <= 1e-9)
            if res.status == "infeasible" and not blind.any():
                res = self._solve(a, np.minimum(b, ab), u_ref)
                fallback = "slack"
                if res.status != "solved":  # numerically stuck at the boundary: the backup itself
                    res = QPResult(u_bk, "solved", res.iterations, res.solver)
        if res.status != "solved":
            reason = "infeasible" if res.status == "infeasible" else "solver_failed"
            return self._brake(state, u_ref, reason, t0, h_crit, rg, res.solver)
        if not np.isfinite(res.u).all():
            return self._brake(state, u_ref, "non_finite", t0, h_crit, rg, res.solver)
        intervening = fallback is not None or bool(np.abs(res.u - u_box).max() > 1e-6)
        return FilterResult(res.u, u_ref, h_crit, rg, intervening, fallback, (time.perf_counter() - t0) * 1e6,
                            res.solver, float(hb[k]), n_rows, yielding, n_obj)

    def _backup(self, state: FilterState, a: np.ndarray, b: np.ndarray, gradients: np.ndarray) -> np.ndarray:
        """The backup input of the slack-relaxed QP (module docstring): of the maximal-braking
        inputs along each row's gradient and the model's braking input, the one whose worst row
        does best, min_i (a_iᵀu - b_i)/|a_i|. With a single gradient this is the maximal braking
        along the critical point's gradient; where two obstacles meet (the field's ridge) the
        gradient at the critical point only knows one of them, and braking away from it would
        drive the robot into the other, whose row the relaxation would then give up."""
        model = self.model
        cands = [model.brake(state)]
        seen: list[np.ndarray] = []
        for g in gradients:
            if all(np.abs(g - o).max() > 1e-6 for o in seen):
                seen.append(g)
                cands.append(model.backup(state, g))
        norm = np.maximum(np.linalg.norm(a, axis=1), 1e-9)
        scores = [float(((a @ u - b) / norm).min()) for u in cands]
        return cands[int(np.argmax(scores))]

    def _solve(self, a: np.ndarray, b: np.ndarray, u_ref: np.ndarray, lo: np.ndarray | None = None,
               hi: np.ndarray | None = None) -> QPResult:
        m = self.model
        lo = m.lo if lo is None else lo
        hi = m.hi if hi is None else hi
        if self._use_active_set:
            res = self._active_set.solve(m.weights, u_ref, a, b, lo, hi)
            if res.status != "failed":
                return res
        # OSQP keeps one sparsity pattern: pad to the largest row count with rows that always hold.
        solver = self.osqp()
        pad = solver.m - a.shape[0]
        if pad > 0:
            a = np.concatenate([a, np.zeros((pad, m.n))])
            b = np.concatenate([b, np.full(pad, -np.inf)])
        return solver.solve(m.weights, u_ref, a, b, lo, hi)

    def _brake(self, state: FilterState, u_ref: np.ndarray, reason: str, t0: float, h: float = 0.0,
               rg: int = 0, solver: str = "") -> FilterResult:
        return FilterResult(self.model.brake(state), u_ref, h, rg, True, reason,
                            (time.perf_counter() - t0) * 1e6, solver)
