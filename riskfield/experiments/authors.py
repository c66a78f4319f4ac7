"""The authors' benchmark protocol (``riskfield bench safety --protocol authors``), as plain objects.

The facts of the authors' published protocol (phai-lab/SafeDF, parent of its
latest commit: ``repro/table_metrics/README_success6_final_experiment.md``,
``scripts/export_scene_specific_semantic_risk_configs.py``, ``scripts/recompute_paper_tables_from_rollouts.py``),
written here in our own code:

* **Risk groups, per scene** (:func:`size_balanced_tiers`). Every non-structural ADE20K class present
  in the scene is sorted by the median diagonal of its objects' oriented bounding boxes (descending;
  ties: more objects first, then name). The sorted classes are cut into chunks of three; chunk ``k``
  takes the tier order ``TIER_ORDERS[k mod 3]`` = (high, mid, low), (mid, low, high), (low, high, mid);
  inside a chunk the classes are sorted by object count (descending), then median diagonal
  (descending), then name, and take the tiers in that order. Margins: high 0.15, mid 0.05, low 0.00 m.
* **Trajectories** (:func:`ring_pairs`). Object-ring sampling: a target object of the group, a start
  and a goal on a ring round its centre at radius (its horizontal half-diagonal + 0.20 m stand-off +
  U(0.05, 0.35) m extra, drawn for each end), the goal opposite the start up to ±15° of angle jitter,
  both at one height within the object's vertical extent. The reference is the straight line start →
  goal, which must collide with the scene (some point of it closer than radius + margin = 0.03 + 0.02 m
  to the mesh); both ends keep a clearance (distance − radius) ≥ 0.20 m and lie inside the scene's
  bounds. 50 per group requested (150 per scene).
  *Matching rule* (the authors' ``rank_matched_cycle`` sampler is not public): pairs are drawn in
  rounds; round ``k`` places the ``k``-th pair of every group in tier order (high, mid, low), each
  with up to ``max_tries`` attempts; the first round in which some group cannot place its pair ends
  the scene and that round is discarded, so every group of a scene has the same count and the pairs
  of equal rank are drawn together.
* **Controller** (:class:`Hocbf`): SaferSplat's double-integrator high-order CBF — the paper's eq. 14,
  Hessian term included (:func:`field_barrier`) — for every barrier row
  ``ḧ + (α+β)ḣ + αβh ≥ 0`` i.e. ``∇hᵀu + vᵀ∇²h v + (α+β)∇hᵀv + αβ h ≥ 0`` with α = 5, β = 1, the QP
  ``min ‖u − u_ref‖²`` over those rows (no input bounds, as SaferSplat's ``cbf/cbf_utils.py``
  ``CBF.solve_QP``) solved by the filter's exact QP (``safety_filter.compiled.ExactQP``), and the reference passed
  through unchanged when the solver fails. Period 0.05 s, at most 500 steps; the nominal input is the
  goal-seeking PD law (``nominal_mode=goal``).
* **Metrics** (:class:`AuthorsRollout` + ``metrics``): progress is ``max_t ‖p_t − s‖ / ‖g − s‖`` (not
  clipped); matched progress is the minimum over the compared methods — for Table I/II *and* Table
  III over all three methods (``recompute_paper_tables_from_rollouts.py``, ``main``: ``matched_progress
  = min(r.progress for r in trio.values())``, and the Table III records are the ESDF rows of those
  trio records); MP clearance is the minimum,
  up to the first step reaching the matched progress, of the *unsigned* distance to the full mesh
  minus the radius (the script uses open3d's ``compute_distance``; the paper's text says signed); MP
  collision is MP clearance < 0; computation time is the mean per-step controller time of each
  trajectory, averaged over trajectories.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from riskfield.experiments.metrics import Rollout
from riskfield.experiments.sampling import Pair
from riskfield.protocol import RiskConfig, ade20k
from riskfield.protocol.risk import RiskGroup
from riskfield.services.fields import DistanceField
from riskfield.services.navigator.clf import PointMassCLF
from riskfield.services.safety_filter.compiled import ExactQP

#: The authors' six ScanNet++ scenes (run them with ``--scannetpp DATA/<id>`` each, or ``--scannetpp DATA``).
AUTHORS_SCENES = ("281bc17764", "689fec23d7", "7cd2ac43b4", "8a20d62ac0", "b26e64c4b0", "bc03d88fc3")
#: Their accepted trajectories per scene (same order) and per group: 486 in all.
AUTHORS_ACCEPTED = (113, 101, 71, 107, 53, 41)
AUTHORS_GROUPS = {"high": 164, "mid": 161, "low": 161}

#: ADE20K classes the authors treat as structure (never grouped, never a target): their
#: ``DEFAULT_EXCLUDED_ADE20K`` list, by name.
STRUCTURAL_NAMES = (
    "wall", "building", "sky", "floor", "tree", "ceiling", "road", "sidewalk", "earth", "mountain", "water",
    "house", "sea", "field", "rock", "column", "path", "stairs", "stairway", "river", "bridge", "fence",
    "railing", "base", "pole", "land", "streetlight", "tower", "awning", "windowpane", "door", "screen door",
    "runway", "traffic light",
)
STRUCTURAL = frozenset(ade20k.index(n) for n in STRUCTURAL_NAMES)
TIERS = ("high", "mid", "low")
TIER_ORDERS = (("high", "mid", "low"), ("mid", "low", "high"), ("low", "high", "mid"))
MARGINS = {"high": 0.15, "mid": 0.05, "low": 0.0}


@dataclass(frozen=True)
class AuthorsConfig:
    """The protocol's numbers (defaults: the authors')."""

    radius: float = 0.03
    margin: float = 0.02  # added to the radius in the straight-line collision test
    standoff: float = 0.20
    extra: tuple[float, float] = (0.05, 0.35)
    jitter_deg: float = 15.0
    min_clearance: float = 0.20
    per_group: int = 50
    max_tries: int = 300
    alpha: float = 5.0
    beta: float = 1.0
    dt: float = 0.05
    steps: int = 500
    k_p: float = 1.0
    k_d: float = 1.6
    v_max: float = 0.5
    a_max: float = 1.5


# -- risk groups ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SceneItem:
    """One non-structural object: its ADE20K class, OBB diagonal and axis-aligned box."""

    index: int
    name: str
    label: int
    diagonal: float
    lo: np.ndarray
    hi: np.ndarray

    @property
    def class_name(self) -> str:
        return ade20k.CLASSES[self.label]


@dataclass(frozen=True)
class ClassTier:
    """A class of the scene with its statistics and assigned tier."""

    label: int
    name: str
    count: int
    median_diagonal: float
    tier: str
    chunk: int


def obb_diagonal(vertices: np.ndarray) -> float:
    """Diagonal of the (minimal-ish) oriented bounding box of ``vertices`` (open3d's PCA-based OBB;
    the axis-aligned box for degenerate point sets)."""
    import open3d as o3d

    v = np.asarray(vertices, dtype=np.float64)
    try:
        obb = o3d.geometry.OrientedBoundingBox.create_from_points(o3d.utility.Vector3dVector(v))
        ext = np.asarray(obb.extent)
    except RuntimeError:
        ext = v.max(0) - v.min(0)
    return float(np.linalg.norm(ext))


def scene_items(objects: Sequence) -> list[SceneItem]:
    """The scene's non-structural single-class objects (multi-class scan parts are structure)."""
    out = []
    for i, o in enumerate(objects):
        if o.triangle_labels is not None or int(o.label) in STRUCTURAL:
            continue
        v = np.asarray(o.world_mesh(0.0)[0], dtype=np.float64)
        out.append(SceneItem(i, o.name, int(o.label), obb_diagonal(v), v.min(0), v.max(0)))
    return out


def size_balanced_tiers(items: Sequence[SceneItem]) -> list[ClassTier]:
    """The authors' per-scene, size-balanced class → tier assignment (see the module docstring)."""
    by_class: dict[int, list[float]] = {}
    for it in items:
        by_class.setdefault(it.label, []).append(it.diagonal)
    stats = [(lab, ade20k.CLASSES[lab], len(d), float(np.median(d))) for lab, d in by_class.items()]
    stats.sort(key=lambda s: (-s[3], -s[2], s[1]))
    out = []
    for k in range(0, len(stats), 3):
        chunk = sorted(stats[k:k + 3], key=lambda s: (-s[2], -s[3], s[1]))
        order = TIER_ORDERS[(k // 3) % len(TIER_ORDERS)]
        for (lab, name, count, med), tier in zip(chunk, order, strict=False):
            out.append(ClassTier(lab, name, count, med, tier, k // 3))
    return out


def scene_risk(tiers: Sequence[ClassTier], margins: Mapping[str, float] = MARGINS) -> RiskConfig:
    """The scene's risk configuration: each tier's classes with its margin; everything else
    (structure, floor and ceiling included: the metric is the distance to the *full* mesh) is an
    obstacle of the low group, whose margin is 0. Gains are the default groups' (they only matter
    to riskfield's own filter row)."""
    default = {g.name: g for g in RiskConfig().groups}
    groups = [RiskGroup(name=t, labels=sorted(c.label for c in tiers if c.tier == t), margin=margins[t],
                        alpha=default[t].alpha, alpha1=default[t].alpha1, alpha2=default[t].alpha2) for t in TIERS]
    return RiskConfig(groups=groups, free_labels=[], default_group="low")


def only_tier(risk: RiskConfig, tier: str | None) -> RiskConfig:
    """``risk`` with every margin 0 except ``tier``'s (``None``: all 0, the plain ESDF)."""
    return risk.model_copy(update={"groups": [g.model_copy(update={"margin": g.margin if g.name == tier else 0.0})
                                              for g in risk.groups]})


# -- object-ring sampling --------------------------------------------------------------------------------

Distance = Callable[[np.ndarray], np.ndarray]
"""Unsigned distance (m) from N×3 points to the full ground-truth mesh."""


def ring_pairs(items_by_tier: Mapping[str, Sequence[SceneItem]], distance: Distance, lo: np.ndarray,
               hi: np.ndarray, rng: np.random.Generator, cfg: AuthorsConfig | None = None,
               first_id: int = 0) -> list[Pair]:
    """Rank-matched object-ring pairs: ``cfg.per_group`` per tier at most, equal counts per tier
    (the tiers with no object are left out). See the module docstring for the rule."""
    cfg = cfg or AuthorsConfig()
    tiers = [t for t in TIERS if items_by_tier.get(t)]
    pairs: list[Pair] = []
    for _ in range(cfg.per_group):
        this_round = []
        for tier in tiers:
            got = None
            for _ in range(cfg.max_tries):
                item = items_by_tier[tier][int(rng.integers(len(items_by_tier[tier])))]
                got = _ring_try(item, distance, lo, hi, rng, cfg)
                if got is not None:
                    this_round.append((item, tier, *got))
                    break
            if got is None:
                return pairs
        for item, tier, start, goal in this_round:
            pairs.append(Pair(first_id + len(pairs), item.name, tier, start, goal))
    return pairs


def _ring_try(item: SceneItem, distance: Distance, lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator,
              cfg: AuthorsConfig) -> tuple[np.ndarray, np.ndarray] | None:
    centre = (item.lo + item.hi) / 2
    half = float(np.linalg.norm(item.hi[:2] - item.lo[:2]) / 2)
    r_s = half + cfg.standoff + rng.uniform(*cfg.extra)
    r_g = half + cfg.standoff + rng.uniform(*cfg.extra)
    theta = rng.uniform(0.0, 2 * math.pi)
    phi = theta + math.pi + math.radians(rng.uniform(-cfg.jitter_deg, cfg.jitter_deg))
    keep = cfg.radius + cfg.min_clearance
    z_lo, z_hi = max(item.lo[2], lo[2] + keep), min(item.hi[2], hi[2] - keep)
    z = rng.uniform(z_lo, z_hi) if z_hi > z_lo else float(centre[2])
    start = np.array([centre[0] + r_s * math.cos(theta), centre[1] + r_s * math.sin(theta), z])
    goal = np.array([centre[0] + r_g * math.cos(phi), centre[1] + r_g * math.sin(phi), z])
    ends = np.stack([start, goal])
    if np.any(ends < lo) or np.any(ends > hi):
        return None
    if np.any(distance(ends) - cfg.radius < cfg.min_clearance):
        return None
    n = max(2, math.ceil(float(np.linalg.norm(goal - start)) / 0.01) + 1)  # 1 cm along the line
    line = start + np.linspace(0.0, 1.0, n)[:, None] * (goal - start)
    if not np.any(distance(line) < cfg.radius + cfg.margin):
        return None  # the straight reference must collide
    return start, goal


# -- controller -------------------------------------------------------------------------------------------

Barrier = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
"""``barrier(p) -> (h (m,), ∇h (m, 3), ∇²h (m, 3, 3))``: the barrier rows at position ``p``."""

_FREE = 1e6  # SaferSplat's QP has no input bounds: a box this wide never binds


class Hocbf:
    """SaferSplat's double-integrator HOCBF safety filter (see the module docstring).

    For each barrier row ``hᵢ``: ``∇hᵢᵀu ≥ −vᵀ∇²hᵢv − (α+β)∇hᵢᵀv − αβhᵢ``; ``u = argmin ‖u − u_ref‖²``.
    ``failed`` counts the steps whose QP had no answer (the reference went through).
    """

    def __init__(self, alpha: float = 5.0, beta: float = 1.0):
        self.alpha, self.beta = alpha, beta
        self._qp: dict[int, ExactQP] = {}  # per row count
        self.failed = 0
        self.relaxed = False  # the last step passed the reference through
        self._w = np.ones(3)
        self._lo, self._hi = np.full(3, -_FREE), np.full(3, _FREE)

    def rows(self, h: np.ndarray, g: np.ndarray, hess: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        curv = np.einsum("i,mij,j->m", v, hess, v)
        return g, -curv - (self.alpha + self.beta) * (g @ v) - self.alpha * self.beta * h

    def __call__(self, barrier: Barrier, p: np.ndarray, v: np.ndarray, u_ref: np.ndarray) -> np.ndarray:
        h, g, hess = barrier(p)
        a, b = self.rows(h, g, hess, v)
        m = a.shape[0]
        if m not in self._qp:
            self._qp[m] = ExactQP(self._w, self._lo, self._hi, m)
        status, u = self._qp[m].solve(np.asarray(u_ref, np.float64), a, b)
        self.relaxed = status != "solved"
        if self.relaxed:
            self.failed += 1
            return np.asarray(u_ref, dtype=float)
        return u


def field_barrier(field: DistanceField, radius: float, hessian: bool = True) -> Barrier:
    """``h = d − r`` of a distance field at the robot's centre, with the field's gradient and Hessian:
    the paper's HOCBF (its eq. 14, ``∇dᵀu + vᵀ∇²d v + α₁∇dᵀv + α₂ d ≥ 0``), whose text says "ESDF
    gradients and Hessians are computed by finite differences and evaluated at query points using
    trilinear interpolation" — what ``EsdfField``'s ``trilinear`` query returns. The authors' ESDF
    controller (``run_scannetpp_esdf_cbf_ref.py --method esdf``, called in
    ``repro/table_metrics/README_success6_final_experiment.md`` § 5 and 6) is not in their release.

    ``hessian=False`` sets ∇²h = 0: a named variant (``authors_bench.ESDF_NO_HESSIAN``) reported
    beside the paper's, never instead of it."""

    def barrier(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = field.query(p[None], hessian=hessian)
        hess = s.hessian if hessian and s.hessian is not None else np.zeros((1, 3, 3))
        return s.distance - radius, s.gradient, hess

    return barrier


# -- roll-outs and metrics -----------------------------------------------------------------------------------


class AuthorsRollout(Rollout):
    """A roll-out scored the authors' way: progress ``‖p_t − s‖ / ‖g − s‖`` (not clipped, its
    maximum over the run is the trajectory's progress); ``clearance`` is the unsigned distance to
    the full mesh minus the radius."""

    @property
    def curve(self) -> np.ndarray:
        d0 = float(np.linalg.norm(self.goal - self.start))
        if d0 <= 0.0:
            return np.ones(len(self.path))
        return np.linalg.norm(self.path - self.start, axis=1) / d0

    @property
    def progress(self) -> float:
        return float(self.curve.max())


Control = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""``control(p, v, u_ref) -> u``; may carry a ``relaxed`` attribute (the last step fell back)."""


def rollout(method: str, pair: Pair, control: Control, clf: PointMassCLF, distance: Distance,
            cfg: AuthorsConfig, scene: str = "") -> AuthorsRollout:
    """Drive the double integrator from the pair's start toward its goal for up to ``cfg.steps``.

    The run ends early only when nothing can change any more: the robot is at rest (speed < 1 mm/s)
    at the goal (within 1 cm), or at rest anywhere for 2 s (a deadlock in front of an obstacle, which
    the deterministic filter holds for the remaining steps)."""
    p, v = pair.start.astype(float).copy(), np.zeros(3)
    goal = pair.goal.astype(float)
    path = np.empty((cfg.steps + 1, 3))
    path[0] = p
    times = np.empty(cfg.steps)
    dt, n, still, relaxed = cfg.dt, 0, 0, 0
    for k in range(cfg.steps):
        u_ref = clf.command(p, v, goal)
        t0 = time.perf_counter()
        u = control(p, v, u_ref)
        times[k] = time.perf_counter() - t0
        relaxed += bool(getattr(control, "relaxed", False))
        p = p + dt * v + (0.5 * dt * dt) * u
        v = v + dt * u
        path[k + 1] = p
        n = k + 1
        speed = float(np.linalg.norm(v))
        if speed < 1e-3 and np.linalg.norm(p - goal) < 0.01:
            break
        still = still + 1 if speed < 1e-3 else 0
        if still * dt >= 2.0:
            break
    path = path[: n + 1]
    clearance = np.asarray(distance(path), dtype=float) - cfg.radius
    return AuthorsRollout(method, pair.pair, pair.group, path, pair.start, goal, clearance, times[:n].copy(),
                          scene=scene, relaxed_steps=relaxed)


def mean_step_time(rollouts: Sequence[Rollout], method: str, group: str | None = None) -> float:
    """The authors' computation time: each trajectory's mean per-step time, averaged over trajectories."""
    means = [float(r.filter_times.mean()) for r in rollouts
             if r.method == method and (group is None or r.group == group) and r.filter_times.size]
    return float(np.mean(means)) if means else float("nan")
