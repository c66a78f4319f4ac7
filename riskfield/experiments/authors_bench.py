"""One run of the authors' protocol (``authors``) over a set of scenes: maps, pairs, roll-outs, metrics.

Per scene: the per-scene risk groups and ring pairs (``authors``); one input stream (the same
frames for every method); one semantic TSDF fed within ``map_budget_s`` whose ESDF is made once per
variant — plain (all margins 0), *target* (only the trajectory's target group inflated: the
authors' semantic ESDF, one field per group) and *scene* (every group inflated by its margin: what a
deployed robot does); the SaferSplat-style Gaussians fitted to the same frames within the plain
ESDF's reconstruction wall time (``safersplat``). Every method drives the same pairs with the same
nominal input; the authors' HOCBF — the paper's eq. 14 with its Hessian term — filters the ESDF
variants and the Gaussians; the same HOCBF with ∇²h = 0 drives the plain and the (primary) semantic
ESDF as named extra rows (``ESDF_NO_HESSIAN``, ``SEM_NO_HESSIAN``); riskfield's own filter
(``SafetyFilter``, model ``double3d``, its defaults, radius 0.03 m) drives over the scene-inflated
ESDF as an extra row.

Table III is matched over the three methods, as the authors' script does
(``recompute_paper_tables_from_rollouts.py``, ``main``); the two-ESDF matching (the paper's caption)
is a second, named table.

A target-mode trajectory whose group has margin 0 (the low group) runs over a field identical to the
plain ESDF, so its roll-out *is* the plain ESDF's roll-out: it is copied, not re-run, which makes the
two rows identical by construction rather than by luck of timing.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from riskfield.experiments import authors as A
from riskfield.experiments.metrics import Rollout, matched, summarise
from riskfield.experiments.safersplat import EllipsoidBarrier, fit_gaussians
from riskfield.experiments.safety_benchmark import Frame, camera_poses, integrate_within_budget, make_case
from riskfield.protocol import RiskConfig
from riskfield.services.fields import EsdfField
from riskfield.services.navigator.clf import PointMassCLF
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.state import FilterState

BASELINE = "SaferSplat-style (Gaussians, ellipsoid CBF)"
ESDF = "Ours (ESDF)"
SEM_TARGET = "Ours (Semantic ESDF, target)"
SEM_SCENE = "Ours (Semantic ESDF, scene)"
RISKFIELD = "riskfield filter (scene semantic ESDF)"
SEMANTIC = {"target": SEM_TARGET, "scene": SEM_SCENE}
#: The same HOCBF with ∇²h = 0 (``authors.field_barrier(hessian=False)``): named variants, beside the paper's.
NO_HESSIAN = ", ∇²h = 0"
ESDF_NO_HESSIAN = ESDF + NO_HESSIAN
SEM_NO_HESSIAN = {"target": SEM_TARGET + NO_HESSIAN, "scene": SEM_SCENE + NO_HESSIAN}


@dataclass
class Scene:
    """A scene to run: its name and objects (``SceneObject`` with ADE20K labels)."""

    name: str
    objects: list


@dataclass
class AuthorsResult:
    rollouts: list[Rollout]
    scenes: list[dict] = field(default_factory=list)  # per scene: tiers, counts, maps
    modes: tuple[str, ...] = ("target", "scene")
    margins: dict[str, float] = field(default_factory=dict)  # per method: extra margin beyond the radius (m)


def esdf_variants(case, frames: Sequence[Frame], budget_s: float, voxel: float, risk: RiskConfig,
                  modes: Sequence[str], scene: bool = False) -> tuple[dict[str, EsdfField], dict]:
    """The ESDF variants from one semantic TSDF fed within the budget: ``plain``, ``target:<tier>``
    for each tier with a non-zero margin, ``scene``."""
    mapper, used, spent = integrate_within_budget(case, frames, budget_s, voxel, risk)
    variants: list[tuple[str, RiskConfig]] = [("plain", A.only_tier(risk, None))]
    if "target" in modes:
        variants += [(f"target:{g.name}", A.only_tier(risk, g.name)) for g in risk.groups if g.margin > 0]
    if "scene" in modes:
        variants.append(("scene", risk))
    fields, finalize = {}, {}
    if "scene" not in modes and scene:
        variants.append(("scene", risk))
    for key, r in variants:
        mapper.set_risk_config(r)
        t0 = time.perf_counter()
        grid = mapper.update_esdf().grid3d
        finalize[key] = time.perf_counter() - t0
        fields[key] = EsdfField.from_grid(grid)
    return fields, dict(frames=used, integrate_s=spent, finalize_s=finalize,
                        reconstruction_s=spent + finalize["plain"])


class _RiskfieldStep:
    """riskfield's ``double3d`` filter as a ``Control`` over one field."""

    def __init__(self, filt: SafetyFilter, field_: EsdfField):
        self.filt, self.field, self.relaxed = filt, field_, False

    def __call__(self, p: np.ndarray, v: np.ndarray, u_ref: np.ndarray) -> np.ndarray:
        res = self.filt.filter(FilterState(p, velocity=v), u_ref, self.field)
        self.relaxed = res.fallback is not None
        return res.u


class _HocbfStep:
    """The authors' HOCBF over one barrier, as a ``Control``."""

    def __init__(self, barrier: A.Barrier, cfg: A.AuthorsConfig):
        self.barrier, self.hocbf = barrier, A.Hocbf(cfg.alpha, cfg.beta)

    @property
    def relaxed(self) -> bool:
        return self.hocbf.relaxed

    def __call__(self, p: np.ndarray, v: np.ndarray, u_ref: np.ndarray) -> np.ndarray:
        return self.hocbf(self.barrier, p, v, u_ref)


def methods_for(modes: Sequence[str], baseline: bool = True, riskfield: bool = True,
                no_hessian: bool = True) -> list[str]:
    """The methods of a run; ``no_hessian`` adds the ∇²h = 0 rows of the ESDF and the first mode."""
    return [*([BASELINE] if baseline else []), ESDF, *(SEMANTIC[m] for m in modes),
            *([ESDF_NO_HESSIAN, SEM_NO_HESSIAN[modes[0]]] if no_hessian and modes else []),
            *([RISKFIELD] if riskfield else [])]


def counterpart(method: str) -> str:
    """The paper's row a named variant stands beside (itself for the paper's rows)."""
    if method == ESDF_NO_HESSIAN:
        return ESDF
    for mode, name in SEM_NO_HESSIAN.items():
        if method == name:
            return SEMANTIC[mode]
    return method


@dataclass(frozen=True)
class RunOptions:
    """What a :func:`run` covers beside its scenes: the semantic modes (the first is the primary),
    the frames of each scene's input stream, the seconds and voxel size its maps are built with,
    the seed of the start/goal pairs, and which methods run beside the ESDFs (``methods_for``)."""

    modes: Sequence[str] = ("target", "scene")
    frames: int = 48
    map_budget_s: float = 6.0
    voxel: float = 0.05
    seed: int = 0
    baseline: bool = True
    riskfield: bool = True
    no_hessian: bool = True


def run(scenes: Sequence[Scene], perceive: Callable, cfg: A.AuthorsConfig | None = None,
        options: RunOptions = RunOptions(), *, on_scene: Callable[[str, int], None] | None = None,
        on_rollout: Callable[[], None] | None = None) -> AuthorsResult:
    """The protocol over ``scenes``; ``on_scene(description, rollouts to come)`` and ``on_rollout()``
    drive a progress bar."""
    cfg = cfg or A.AuthorsConfig()
    o = options
    modes, baseline, riskfield = o.modes, o.baseline, o.riskfield
    clf = PointMassCLF(cfg.k_p, cfg.k_d, cfg.v_max, cfg.a_max)
    methods = methods_for(modes, baseline, riskfield, o.no_hessian)
    rollouts: list[Rollout] = []
    info: list[dict] = []
    # The authors' HOCBF keeps h = d − r: no margin beyond the radius; riskfield's filter keeps δ + half a voxel.
    margins = {m: 0.0 for m in methods}
    first_id = 0
    for si, sc in enumerate(scenes):
        items = A.scene_items(sc.objects)
        tiers = A.size_balanced_tiers(items)
        risk = A.scene_risk(tiers)
        case = make_case(sc.name, sc.objects, risk, margin=0.0)
        snap = case.scene.at(0.0)
        distance = snap.distance
        tier_of = {c.label: c.tier for c in tiers}
        by_tier = {t: [it for it in items if tier_of[it.label] == t] for t in A.TIERS}
        rng = np.random.default_rng([o.seed, si, 14])
        pairs = A.ring_pairs(by_tier, distance, case.lo, case.hi, rng, cfg, first_id)
        first_id += len(pairs)
        row = dict(scene=sc.name, objects=len(items), pairs=len(pairs),
                   requested=cfg.per_group * len(A.TIERS),
                   groups={t: sum(p.group == t for p in pairs) for t in A.TIERS},
                   tiers=[dataclasses.asdict(c) for c in tiers])
        info.append(row)
        if on_scene:
            on_scene(f"{sc.name}: maps", len(pairs) * len(methods))
        if not pairs:
            continue
        stream = [perceive(snap, T) for T in camera_poses(case, o.frames)]
        fields, esdf_info = esdf_variants(case, stream, o.map_budget_s, o.voxel, risk, modes, scene=riskfield)
        row["esdf"] = esdf_info
        controls: dict[str, Callable] = {ESDF: _HocbfStep(A.field_barrier(fields["plain"], cfg.radius), cfg),
                                         ESDF_NO_HESSIAN: _HocbfStep(A.field_barrier(fields["plain"], cfg.radius,
                                                                                     hessian=False), cfg)}
        if baseline:
            gmap = fit_gaussians(stream, esdf_info["reconstruction_s"])
            row["gaussians"] = dict(count=len(gmap), frames=gmap.frames, build_s=gmap.build_s)
            controls[BASELINE] = _HocbfStep(EllipsoidBarrier(gmap, cfg.radius), cfg)
        target = {(t, h): _HocbfStep(A.field_barrier(fields[f"target:{t}"], cfg.radius, hessian=h), cfg)
                  for t in A.TIERS if f"target:{t}" in fields for h in (True, False)}
        if "scene" in modes:
            for h, name in ((True, SEM_SCENE), (False, SEM_NO_HESSIAN["scene"])):
                controls[name] = _HocbfStep(A.field_barrier(fields["scene"], cfg.radius, hessian=h), cfg)
        if riskfield:
            fc = FilterConfig(model="double3d", robot_radius=cfg.radius, rate_hz=1.0 / cfg.dt)
            step = _RiskfieldStep(SafetyFilter(fc, risk), fields["scene"])
            controls[RISKFIELD] = step
            margins[RISKFIELD] = float(step.filt.delta + fc.map_margin_voxels * fields["scene"].voxel_size)
        if on_scene:
            on_scene(f"{sc.name}: roll-outs", 0)
        for pair in pairs:
            done: dict[str, Rollout] = {}
            for m in methods:
                if m in (SEM_TARGET, SEM_NO_HESSIAN["target"]):
                    hess = m == SEM_TARGET
                    if (pair.group, hess) in target:
                        done[m] = A.rollout(m, pair, target[(pair.group, hess)], clf, distance, cfg, sc.name)
                    else:  # margin 0: the target field is the plain ESDF
                        done[m] = dataclasses.replace(done[ESDF if hess else ESDF_NO_HESSIAN], method=m)
                else:
                    done[m] = A.rollout(m, pair, controls[m], clf, distance, cfg, sc.name)
                if on_rollout:
                    on_rollout()
            rollouts.extend(done[m] for m in methods)
    return AuthorsResult(rollouts, info, tuple(modes), margins)


# -- metrics -------------------------------------------------------------------------------------------------


#: A roll-out whose progress exceeds this left the object ring far behind (flung away by the unbounded
#: QP: the paper's HOCBF has no input bounds); its unclipped progress dominates the mean, so it is counted.
RUNAWAY = 2.0


def _row(rollouts: Sequence[Rollout], mp: dict, method: str, group: str | None = None) -> dict:
    d = summarise(rollouts, mp, method, group).as_dict()
    d["computation_time_s"] = A.mean_step_time(rollouts, method, group)  # the authors' mean of means
    d["runaway"] = sum(1 for r in rollouts if r.method == method and (group is None or r.group == group)
                       and r.progress > RUNAWAY)
    return d


def _matched_with(rs: Sequence[Rollout], trio: Sequence[str], method: str) -> dict:
    """MP clearances of ``method`` matched with ``trio``, the paper's row it stands beside replaced by it."""
    group = tuple(method if m == counterpart(method) else m for m in trio)
    if method not in group:
        group = (*[m for m in trio if m != trio[-1]], method)  # an extra method: in place of the third
    return {k: v for k, v in matched(rs, group).items() if k[0] == method}


def tables(result: AuthorsResult, primary: str) -> dict:
    """Table II (the baseline, the ESDF and the primary semantic ESDF matched together; a ∇²h = 0
    row matched with the other two in place of its own; every other row in place of the third),
    Table III per semantic mode matched over the three methods as the authors' script does
    (``table3_by_mode``) and over the two ESDF variants (``table3_two_method_by_mode``), full-run
    figures and counts."""
    rs = result.rollouts
    present = list(dict.fromkeys(r.method for r in rs))
    base = [m for m in (BASELINE, ESDF) if m in present]
    sem = SEMANTIC[primary]
    trio = (*base, sem)
    mp_trio = matched(rs, trio) if rs else {}
    t2 = {m: _row(rs, mp_trio, m) for m in trio}
    for m in present:
        if m not in trio:
            t2[m] = _row(rs, _matched_with(rs, trio, m), m)
    for m, row in t2.items():
        row["margin_m"] = result.margins.get(m)
    t3_by_mode, t3_two, t3_overall = {}, {}, {}
    for mode in result.modes:
        three = (*base, SEMANTIC[mode])
        mp3 = matched(rs, three) if rs else {}
        mp2 = matched(rs, (ESDF, SEMANTIC[mode])) if rs else {}
        t3_by_mode[mode] = {g: {"esdf": _row(rs, mp3, ESDF, g), "semantic": _row(rs, mp3, SEMANTIC[mode], g)}
                            for g in A.TIERS}
        t3_two[mode] = {g: {"esdf": _row(rs, mp2, ESDF, g), "semantic": _row(rs, mp2, SEMANTIC[mode], g)}
                        for g in A.TIERS}
        t3_overall[mode] = {"esdf": _row(rs, mp3, ESDF), "semantic": _row(rs, mp3, SEMANTIC[mode])}
    per_scene = {}
    for r in rs:
        if r.method == ESDF:
            c = per_scene.setdefault(r.scene, {t: 0 for t in A.TIERS})
            c[r.group] += 1
    groups = {t: sum(c[t] for c in per_scene.values()) for t in A.TIERS}
    full = {m: {g or "all": {k: v for k, v in summarise(rs, {(r.method, r.pair): 0.0 for r in rs}, m, g)
                             .as_dict().items() if k in ("n", "collision_rate", "min_clearance_m",
                                                         "min_clearance_mean_m", "relaxed_fraction")}
                for g in (None, *A.TIERS)} for m in present}
    return dict(table2=t2, table3=t3_by_mode[primary], table3_by_mode=t3_by_mode,
                table3_matching=" / ".join(trio), table3_two_method_by_mode=t3_two, table3_overall=t3_overall,
                full_run=full, per_scene_groups=per_scene, groups=groups,
                trajectories=len({r.pair for r in rs}))


def per_trajectory(result: AuthorsResult, primary: str) -> list[dict]:
    """Every roll-out with its scores (MP clearance within the Table II trio and the Table III pair)."""
    rs = result.rollouts
    methods = list(dict.fromkeys(r.method for r in rs))
    base = [m for m in (BASELINE, ESDF) if m in methods]
    trio = (*base, SEMANTIC[primary])
    mp2: dict = dict(matched(rs, trio)) if rs else {}
    for m in methods:
        if m not in trio:
            mp2.update(_matched_with(rs, trio, m))
    mp3 = {mode: matched(rs, (*base, SEMANTIC[mode])) for mode in result.modes}
    mp3_two = {mode: matched(rs, (ESDF, SEMANTIC[mode])) for mode in result.modes}
    return [dict(pair=r.pair, scene=r.scene, method=r.method, group=r.group, progress=r.progress,
                 mp_clearance_table2=mp2.get((r.method, r.pair)),
                 mp_clearance_table3={mode: mp3[mode].get((r.method, r.pair))
                                      for mode in result.modes if r.method in (ESDF, SEMANTIC[mode])},
                 mp_clearance_table3_two_method={mode: mp3_two[mode].get((r.method, r.pair))
                                                 for mode in result.modes if r.method in (ESDF, SEMANTIC[mode])},
                 min_clearance=r.min_clearance, steps=len(r.filter_times), relaxed_steps=r.relaxed_steps,
                 step_time_mean_s=float(r.filter_times.mean()) if r.filter_times.size else None,
                 start=r.start, goal=r.goal) for r in rs]
