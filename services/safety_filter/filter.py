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
and the braking input, the one whose worst row does best (``compiled._relax``):

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
from riskfield.protocol import field as field_query

from ..fields import DistanceField, EsdfField, FieldSample
from . import compiled
from .barriers import BarrierModel
from .compiled import CompiledStep
from .config import FilterConfig
from .model import ALPHA1, ALPHA2
from .state import FilterState

_ZERO3 = np.zeros(3)


def hocbf_gains(alpha1: float, alpha2: float) -> tuple[float, float]:
    """(α₁, α₂) with real roots of s² + α₁ s + α₂, lowering α₂ to α₁²/4 if needed.

    With complex roots the equality ḧ + α₁ ḣ + α₂ h = 0 oscillates and h crosses zero, so the
    HOCBF would not keep the safe set invariant; critical damping is the closest safe choice.
    """
    return alpha1, min(alpha2, alpha1 * alpha1 / 4.0)


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
    rows: int = 0  # CBF rows in the QP
    yielding: bool = False  # a yielding row asked more than stopping: the robot stops and waits
    object_rows: int = 0  # moving objects on a collision course, each its own row


class SafetyFilter:
    """The pure filter: config → model + the compiled step (:mod:`.compiled`); ``filter()`` once per
    control step."""

    def __init__(self, config: FilterConfig | None = None, risk: RiskConfig | None = None, warm_up: bool = True,
                 model: BarrierModel | None = None):
        """``warm_up=False`` defers :meth:`warm_up` to the caller (a node subscribes first). ``model``
        replaces the one the configuration builds (a model of one's own, described by a ``ModelSpec``)."""
        self.config = config or FilterConfig()
        self.model: BarrierModel = model if model is not None else self.config.build_model()
        self.delta = self.config.margin(self.model)
        self.gains = GainTable(risk or RiskConfig(), self.config.yield_labels)
        first_order = not self.model.needs_hessian
        self._alpha_cap = self.model.alpha_cap(self.config.a_max) if first_order else math.inf
        self._wrapped: tuple[EsdfField, EsdfField] | None = None
        self._step = CompiledStep(self.model, self.config, self.delta, self._alpha_cap)
        if warm_up:
            self.warm_up()

    def warm_up(self) -> None:
        """Compile the step (or load it from numba's on-disk cache: ~0.5 s; a cold cache compiles for
        ~20 s) with the control loop's argument types: call before the first step. The model's
        functions the supervisor calls on a brake are loaded too, so that no first load stalls a
        step in the loop."""
        self._step.warm_up(self.gains.for_groups(()))
        s = FilterState(np.array([0.15, 0.15, 0.0 if self.model.spec.attitude == "yaw" else 0.15]))
        self.model.integrate(s, np.zeros(self.model.n), self.config.dt)
        self.model.backup(s, np.array([1.0, 0.0, 0.0]))
        self.model.brake(s)
        field_query.warm_up()  # the clearance and the evasion read the field outside the step

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
        """
        t0 = time.perf_counter()
        if objects is not None and (not self.config.object_motion or len(objects) == 0):
            objects = None
        if objects is not None:
            objects = np.ascontiguousarray(objects[:compiled.MAX_OBJECTS], np.float64)
        u_ref = np.asarray(u_ref, np.float64)
        ang = _ZERO3 if angular is None else np.asarray(angular, np.float64)
        if u_ref.shape != (self.model.n,) or ang.shape != (3,):
            return self._brake(state, u_ref, "non_finite", t0)
        field = self.field_for(field)
        step = self._step
        step.run(state, u_ref, ang, field, self.gains.for_groups(field.groups), objects)
        code, rg, n_rows, intervening, yielding, n_obj = step.out_i.tolist()
        h, margin = step.out_f.tolist()
        fallback = compiled.FALLBACK[code]
        if code not in (compiled.OK, compiled.SLACK):
            # n_rows is set once the rows are built: from then on the QP had its say.
            return self._brake(state, u_ref, fallback, t0, h, rg, compiled.SOLVER if n_rows else "")
        return FilterResult(step.u.copy(), u_ref, h, rg, bool(intervening), fallback,
                            (time.perf_counter() - t0) * 1e6, compiled.SOLVER, margin, n_rows, bool(yielding), n_obj)

    def _brake(self, state: FilterState, u_ref: np.ndarray, reason: str, t0: float, h: float = 0.0,
               rg: int = 0, solver: str = "") -> FilterResult:
        return FilterResult(self.model.brake(state), u_ref, h, rg, True, reason,
                            (time.perf_counter() - t0) * 1e6, solver)
