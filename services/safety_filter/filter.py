"""The CBF-QP safety filter core: one step from (state, reference, field) to a safe input.

    min_u  ½ (u - u_ref)ᵀ W (u - u_ref)   s.t.  A(x) u ≥ b(x),  u ∈ U

Each barrier point adds a row built from the field's distance, gradient (and Hessian) at that
point and the gains of the risk group of its nearest obstacle (:class:`GainTable`). Rows that
hold for every input in the box (b ≤ min_{u∈U} aᵀu) are dropped before the QP: they cannot
be active, and the exact active-set path stays small with a whole-body cover.

Soft predictive rows. The predictive rows (``QpParams.predictive_rows``) anticipate: each pairs
the current barrier with the gradient found one period ahead, so that the robot starts braking
for the obstacle about to become nearest before it is. They are not needed to keep {h_b ≥ 0}
forward invariant — the current rows are the CBF condition of the barrier at the sampling
instant — and where the nearest obstacle changes within the period (the distance field's
ridge: |∇²d| of 15-40 m⁻¹ on the smoothed 5 cm ESDF) the curvature term vᵀ∇²d v at the point
ahead can ask more deceleration than the box holds while the current rows are easily met. An
infeasible QP is therefore first solved with only the predictive rows relaxed, as below (each
to what the backup u_bk achieves, A_ahead u ≥ min(b_ahead, A_ahead u_bk)), and the current rows
hard; when that has a solution the step certifies the barrier and is not a fallback. Only when
the current rows themselves conflict is every row relaxed.

Infeasible QP (fallback ``slack``). With the barrier's stopping condition a state inside the
safe set keeps the QP feasible (``barriers``); a moved obstacle or a new map can still leave
none. Then the filter solves the same QP with every row relaxed to what the backup input u_bk
achieves — of the maximal-braking inputs along each row's gradient (``BarrierModel.backup``)
and the braking input, the one whose worst row does best (``SafetyFilter._backup``):

    min_u ½ (u - u_ref)ᵀ W (u - u_ref)   s.t.  A u ≥ min(b, A u_bk),  u ∈ U.

u_bk is feasible by construction, so this always has a solution, and every row — every
point's barrier rate — is at least as good as under the backup (the slack of row i is
max(0, b_i - a_iᵀu_bk), the backup's own violation); within that it stays closest to the
reference. The step is reported with ``fallback = "slack"`` and the command is the relaxed
solution (not zero). Anything else doubtful — a point outside the map, a non-finite number, a
solver failure — yields the braking input and a ``fallback`` reason.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import RiskConfig, ade20k

from ..fields import DistanceField, EsdfField, FieldSample
from . import compiled
from . import model as mdl
from .barriers import BarrierModel
from .compiled import CompiledStep
from .config import FilterConfig
from .model import ALPHA1, ALPHA2, OBJECT_COLUMNS, YIELD
from .qp import ActiveSetSolver, OsqpSolver, QPResult
from .state import FilterState

_ZERO3 = np.zeros(3)
#: Above this many rows the exact active-set path hands over to OSQP: the field's rows of a body of
#: up to 8 points now and ahead, and the two rows of each of 8 moving objects (most of them hold on
#: the whole box and are dropped before the QP).
ACTIVE_SET_MAX_ROWS = 40


def hocbf_gains(alpha1: float, alpha2: float) -> tuple[float, float]:
    """(α₁, α₂) with real roots of s² + α₁ s + α₂, lowering α₂ to α₁²/4 if needed.

    With complex roots the equality ḧ + α₁ ḣ + α₂ h = 0 oscillates and h crosses zero, so the
    HOCBF would not keep the safe set invariant; critical damping is the closest safe choice.
    """
    return alpha1, min(alpha2, alpha1 * alpha1 / 4.0)


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float64)


def _rows_of(s: FieldSample, rows: slice) -> FieldSample:
    return FieldSample(s.distance[rows], s.gradient[rows], None if s.hessian is None else s.hessian[rows],
                       s.risk_group[rows], s.inside[rows])


class GainTable:
    """Per risk group id of a field: [α, α₁, α₂, margin, yield] from the risk configuration.

    Field groups are matched to configured groups by name (``EsdfGrid.groups[id - 1]``). Id 0
    (no obstacle recorded) and names the configuration does not know get the most
    conservative values: the smallest gains and the largest margin, and no yielding (an unknown
    obstacle keeps the static barrier's recovery). A group yields (``model.YIELD``) when it holds
    one of ``yield_labels`` (ADE20K names): its obstacles may slow and stop the robot, never push it.
    """

    def __init__(self, risk: RiskConfig, yield_labels: Sequence[str] = ()):
        self.risk = risk
        self.yield_labels = tuple(yield_labels)
        yielding = {ade20k.index(n) for n in self.yield_labels}
        rows = {}
        for g in risk.groups:
            a1, a2 = hocbf_gains(g.alpha1, g.alpha2)
            rows[g.name] = (g.alpha, a1, a2, g.margin, 1.0 if yielding & set(g.labels) else 0.0)
        self._rows = rows
        vals = np.array(list(rows.values()))
        self.conservative = np.array([vals[:, 0].min(), vals[:, 1].min(), 0.0, vals[:, 3].max(), 0.0])
        self.conservative[ALPHA2] = hocbf_gains(self.conservative[ALPHA1], vals[:, 2].min())[1]
        self._cache: dict[tuple[str, ...], np.ndarray] = {}

    def for_groups(self, groups: Sequence[str]) -> np.ndarray:
        key = tuple(groups)
        table = self._cache.get(key)
        if table is None:
            table = np.array([self.conservative, *[self._rows.get(n, self.conservative) for n in key]], np.float64)
            self._cache[key] = table
        return table


@dataclass(frozen=True)
class FilterResult:
    """One filter step. ``u`` is the model input: the braking input when ``fallback`` is set,
    except for ``"slack"``, where it is the relaxed QP's solution (module docstring)."""

    u: np.ndarray
    u_ref: np.ndarray
    h: float  # d - r at the critical point (0.0 when unknown)
    risk_group: int  # field group id at the critical point (0 = none or unknown)
    intervening: bool
    fallback: str | None
    solve_us: float
    solver: str = ""
    margin: float = 0.0  # the barrier h - δ (- margin) at the critical point
    qp_us: float = 0.0  # of solve_us (field query + rows + QP), the QP alone
    rows: int = 0  # CBF rows in the QP
    yielding: bool = False  # a yielding row asked more than stopping: the robot stops and waits
    object_rows: int = 0  # moving objects on a collision course, each its own row
    backend: str = "numpy"  # which step computed it: "numba" (compiled) or "numpy"


class SafetyFilter:
    """The pure filter: config → model + solvers; ``filter()`` once per control step."""

    def __init__(self, config: FilterConfig | None = None, risk: RiskConfig | None = None, warm_up: bool = True,
                 model: BarrierModel | None = None):
        """``warm_up=False`` defers :meth:`warm_up` to the caller (a node subscribes first). ``model``
        replaces the one the configuration builds (a model of one's own, described by a ``ModelSpec``)."""
        self.config = config or FilterConfig()
        self.model: BarrierModel = model if model is not None else self.config.build_model()
        self.delta = self.config.margin(self.model)
        self.gains = GainTable(risk or RiskConfig(), self.config.yield_labels)
        self._active_set = ActiveSetSolver()
        self._osqp: OsqpSolver | None = None
        self.max_object_rows = self.config.max_object_rows if self.config.object_motion else 0
        self.rows_max = self.model.m * (2 if self.config.predictive_rows else 1) + 2 * self.max_object_rows
        self._use_active_set = self.config.solver != "osqp" and self.rows_max <= ACTIVE_SET_MAX_ROWS
        if self.config.solver == "active_set" and not self._use_active_set:
            raise ValueError(f"the active-set solver handles at most {ACTIVE_SET_MAX_ROWS} rows")
        self._first_order = model_is_first_order = not self.model.needs_hessian
        self._alpha_cap = self.model.alpha_cap(self.config.a_max) if model_is_first_order else math.inf
        self._wrapped: tuple[EsdfField, EsdfField] | None = None
        self._compiled = self._build_compiled()
        if warm_up:
            self.warm_up()

    def warm_up(self) -> None:
        """Compile the compiled step (or load it from numba's on-disk cache: ~0.5 s; a cold cache
        compiles for ~20 s) with the control loop's argument types: call before the first step.
        The numpy path's model functions (``model``) are loaded too: the supervisor reads the
        barrier with them on every brake, and a first load in the loop would stall a step."""
        if self._compiled is not None:
            self._compiled.warm_up(self.gains.for_groups(()))
        planar = self.model.spec.attitude == "yaw"
        shape = (4, 4, 1) if planar else (4, 4, 4)
        field = EsdfField(np.ones(shape, np.float32), (0.0, 0.0, 0.0), 0.1, interpolation=self.config.interpolation)
        s = FilterState(np.array([0.15, 0.15, 0.0 if planar else 0.15]))
        self._filter_numpy(s, np.zeros(self.model.n), field, None, time.perf_counter(), np.zeros((1, OBJECT_COLUMNS)))
        self.object_rows(s, np.zeros(self.model.n), self.model.points(s), np.zeros((1, OBJECT_COLUMNS)),
                         self.gains.for_groups(()), self.delta, _ZERO3)
        self.model.integrate(s, np.zeros(self.model.n), self.config.dt)
        self.model.backup(s, np.array([1.0, 0.0, 0.0]))
        self.model.brake(s)

    def _build_compiled(self) -> CompiledStep | None:
        """The compiled step (``compiled``) when the backend allows it and numba is installed."""
        backend = self.config.backend
        if backend == "numpy":
            return None
        if not compiled.HAVE_NUMBA or not self._use_active_set:
            if backend == "numba":
                raise ValueError("backend 'numba' needs numba installed and the active-set QP "
                                 f"(solver 'auto' or 'active_set', at most {ACTIVE_SET_MAX_ROWS} rows)")
            return None
        cfg = self.config
        return CompiledStep(self.model, self.delta, self._alpha_cap, cfg.dt, cfg.predictive_rows,
                            cfg.margins_in_filter, cfg.slack, cfg.map_margin_voxels, max(self.max_object_rows, 1),
                            cfg.collision_horizon_s, cfg.a_max, cfg.object_sweep_s)

    @property
    def backend(self) -> str:
        """``numba`` when steps on an ``EsdfField`` run compiled, else ``numpy``."""
        return "numpy" if self._compiled is None else "numba"

    def field_for(self, field: DistanceField) -> DistanceField:
        """An ``EsdfField`` read with the configured interpolation (the wrap is kept per map)."""
        if not isinstance(field, EsdfField) or field.interpolation == self.config.interpolation:
            return field
        if self._wrapped is None or self._wrapped[0] is not field:
            self._wrapped = (field, field.with_interpolation(self.config.interpolation))
        return self._wrapped[1]

    @property
    def risk(self) -> RiskConfig:
        return self.gains.risk

    def set_risk(self, risk: RiskConfig) -> None:
        self.gains = GainTable(risk, self.config.yield_labels)

    def osqp(self) -> OsqpSolver:
        if self._osqp is None:
            self._osqp = OsqpSolver(self.model.n, self.rows_max)
        return self._osqp

    def gains_at(self, field: DistanceField, sample: FieldSample) -> np.ndarray:
        """[α, α₁, α₂, margin] of each sample's risk group (``GainTable``) on ``field``."""
        table = self.gains.for_groups(field.groups)
        return table[np.minimum(sample.risk_group, table.shape[0] - 1)]

    def barrier(self, state: FilterState, field: DistanceField) -> tuple[float, int, bool]:
        """(h = d - r at the critical point, its risk group id, all points inside the map)."""
        sample = self.field_for(field).query(self.model.points(state))
        h = sample.distance - self.model.radius
        k = int(np.argmin(h))
        return float(h[k]), int(sample.risk_group[k]), bool(sample.inside.all())

    def filter(self, state: FilterState, u_ref: np.ndarray, field: DistanceField,
               angular: np.ndarray | None = None, objects: np.ndarray | None = None) -> FilterResult:
        """The safe input closest to ``u_ref`` (model input space; see the barrier models).

        ``angular`` is the body-frame angular velocity passed through by single integrators.
        ``objects`` are the moving objects predicted to the instant the command takes effect
        (``motion.object_table``; ignored with ``object_motion`` off): each one on a collision
        course adds its own row (``model``). None or no rows: the static barrier.
        On an ``EsdfField`` with the numba backend the step runs compiled (:mod:`.compiled`, the same
        semantics; ``qp_us`` is then not measured apart and reads 0); otherwise with numpy.
        """
        t0 = time.perf_counter()
        if objects is not None and (not self.config.object_motion or len(objects) == 0):
            objects = None
        if objects is not None:
            objects = np.ascontiguousarray(objects[:compiled.MAX_OBJECTS], np.float64)
        if self._compiled is not None:
            grid = self.field_for(field)
            if isinstance(grid, EsdfField):
                res = self._filter_compiled(self._compiled, state, u_ref, grid, angular, t0, objects)
                if res is not None:
                    return res
        return self._filter_numpy(state, u_ref, field, angular, t0, objects)

    def _filter_compiled(self, step: CompiledStep, state: FilterState, u_ref: np.ndarray, field: EsdfField,
                         angular: np.ndarray | None, t0: float,
                         objects: np.ndarray | None = None) -> FilterResult | None:
        """One compiled call; None hands the step to the numpy path (``compiled.HANDBACK``)."""
        u_ref = np.asarray(u_ref, np.float64)
        if u_ref.shape != (self.model.n,):
            return self._brake(state, u_ref, "non_finite", t0)
        ang = _ZERO3 if angular is None else np.asarray(angular, np.float64)
        if ang.shape != (3,):
            return None
        step.run(state.position, state.rotation, state.velocity, u_ref, ang, field,
                 self.gains.for_groups(field.groups), objects)
        code, rg, n_rows, intervening, yielding, n_obj = step.out_i.tolist()
        if code == compiled.HANDBACK:
            return None
        h, margin = step.out_f.tolist()
        fallback = compiled.FALLBACK[code]
        if code not in (compiled.OK, compiled.SLACK):
            # n_rows is set once the rows are built: from then on the QP had its say.
            return self._brake(state, u_ref, fallback, t0, h, rg, ActiveSetSolver.name if n_rows else "")
        return FilterResult(step.u.copy(), u_ref, h, rg, bool(intervening), fallback,
                            (time.perf_counter() - t0) * 1e6, ActiveSetSolver.name, margin, 0.0, n_rows,
                            bool(yielding), n_obj, "numba")

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
            t = mdl.object_course(model.df, model.dl, pts, v_ref, _f64(state.velocity), obj, float(g[mdl.MARGIN]),
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
                i, hb = mdl.object_sample(model.df, model.dl, pts, obj, g, delta, cfg.object_sweep_s * part, grads[q],
                                          hess, wobj)
                b[q] = mdl.point_row(model.di, model.df, model.dl, rot, ang, _f64(state.velocity), i, grads[q], hess,
                                     hb, g, wobj, a[q])
        return a, b, grads

    def _filter_numpy(self, state: FilterState, u_ref: np.ndarray, field: DistanceField,
                      angular: np.ndarray | None, t0: float, objects: np.ndarray | None = None) -> FilterResult:
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
        field = self.field_for(field)
        both = field.query(pts, hessian=model.needs_hessian)
        sample = _rows_of(both, slice(0, m))
        clearance = sample.distance - model.radius
        gains = self.gains_at(field, both)
        if self._first_order:
            gains = gains.copy()
            gains[:, 0] = np.minimum(gains[:, 0], self._alpha_cap)
        hb = np.empty(m)
        delta = self.delta + self.config.map_margin_voxels * getattr(field, "voxel_size", 0.0)
        k = mdl.barriers(model.di, model.df, model.dl, _f64(sample.distance), _f64(sample.gradient),
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
                                          self.gains.for_groups(field.groups), delta, ang)
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
        tq = time.perf_counter()
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
        qp_us = (time.perf_counter() - tq) * 1e6
        if res.status != "solved":
            reason = "infeasible" if res.status == "infeasible" else "solver_failed"
            return self._brake(state, u_ref, reason, t0, h_crit, rg, res.solver)
        if not np.isfinite(res.u).all():
            return self._brake(state, u_ref, "non_finite", t0, h_crit, rg, res.solver)
        intervening = fallback is not None or bool(np.abs(res.u - u_box).max() > 1e-6)
        return FilterResult(res.u, u_ref, h_crit, rg, intervening, fallback, (time.perf_counter() - t0) * 1e6,
                            res.solver, float(hb[k]), qp_us, n_rows, yielding, n_obj)

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
