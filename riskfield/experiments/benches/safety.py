"""``riskfield bench safety``: the paper's simulation benchmark (Tables II and III).

Six procedural scenes by default (``--scannetpp DIR`` adds ScanNet++ scenes), object-centric
start/goal pairs split evenly over the scenes, three methods on identical pairs, and the
paper's metrics. Every method is stated with its extra margin beyond the robot radius
(``margin_m`` in ``summary.json``), and each ESDF variant is also driven with no extra margin
(the default filter, the other barrier where it can differ, the paper's HOCBF on the trilinear
field: ``safety_benchmark.variants``). Writes ``tables.md``, ``summary.json`` (every number, every
trajectory) and plots into ``--out``. See ``safety_benchmark`` for the protocol.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from riskfield.experiments.authors_bench import RunOptions
from riskfield.experiments.benches.safety_authors import authors_run
from riskfield.experiments.metrics import Rollout, matched, summarise
from riskfield.experiments.safety_benchmark import (
    ESDF,
    METHODS,
    POINTCLOUD,
    SEMANTIC,
    BenchConfig,
    build_esdf_maps,
    build_pointcloud,
    camera_poses,
    filter_safe_control,
    gt_perception,
    make_case,
    pairs_for,
    procedural_case,
    rollout,
    sim_perception,
    variants,
)
from riskfield.experiments.scannetpp import load_scene, scannetpp_folders
from riskfield.experiments.tables import plot_safety, safety_table, table2, table3, write_json
from riskfield.options import grouped
from riskfield.protocol import RiskConfig
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.navigator.clf import PointMassCLF
from riskfield.services.simulator.camera import Renderer

app = typer.Typer(add_completion=False)


@dataclass(frozen=True)
class SafetyOptions:
    """The options of ``riskfield bench safety`` (:func:`safety`) but the authors' protocol's own."""

    trajectories: Annotated[int, typer.Option(help="Matched start/goal pairs in total (paper: 486).")] = 486
    scenes: Annotated[int, typer.Option(help="Procedural scenes.")] = 6
    perception: Annotated[str, typer.Option(help="gt (exact pointmaps) or sim (FM-like degraded).")] = "gt"
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("bench_out/safety")
    map_budget: Annotated[float, typer.Option(help="Seconds each method may spend integrating frames.")] = 6.0
    frames: Annotated[int, typer.Option(help="Frames in each scene's input stream.")] = 48
    robot_radius: Annotated[float, typer.Option(help="Robot radius (m), subtracted from every distance.")] = 0.15
    seed: Annotated[int, typer.Option(help="Seed of scenes and pairs.")] = 0
    scannetpp: Annotated[list[Path] | None, typer.Option(
        help="ScanNet++ scene folder, or a data folder of scenes (repeatable).")] = None
    protocol: Annotated[str, typer.Option(
        help="riskfield (this project's benchmark) or authors (the paper's published protocol).")] = "riskfield"


@dataclass(frozen=True)
class AuthorsOptions:
    """The options of the authors' protocol (``--protocol authors``)."""

    semantic: Annotated[str, typer.Option(
        help="authors protocol: target (only the target's group inflated, the authors'), scene (every group "
             "inflated) or both (target is primary).")] = "both"
    per_group: Annotated[int, typer.Option(help="authors protocol: pairs requested per risk group and scene.")] = 50
    baseline: Annotated[bool, typer.Option(help="authors protocol: run the SaferSplat-style baseline.")] = True


@app.command()
@grouped
def safety(
    o: SafetyOptions = SafetyOptions(),
    authors: AuthorsOptions = AuthorsOptions(),
) -> None:
    """Equal-time comparison of a point-cloud CBF, the ESDF and the semantic ESDF (3-D double integrator)."""
    if o.perception not in ("gt", "sim"):
        raise typer.BadParameter("perception must be gt or sim")
    if o.protocol not in ("riskfield", "authors"):
        raise typer.BadParameter("protocol must be riskfield or authors")
    folders = [f for root in o.scannetpp or [] for f in scannetpp_folders(root)]
    if o.protocol == "authors":
        if authors.semantic not in ("target", "scene", "both"):
            raise typer.BadParameter("semantic must be target, scene or both")
        modes = ("target", "scene") if authors.semantic == "both" else (authors.semantic,)
        options = RunOptions(modes=modes, frames=o.frames, map_budget_s=o.map_budget, seed=o.seed,
                             baseline=authors.baseline)
        authors_run(o.out, scenes=o.scenes, folders=folders, perception=o.perception, per_group=authors.per_group,
                    options=options)
        return
    console = Console()
    cfg = BenchConfig(trajectories=o.trajectories, scenes=o.scenes, perception=o.perception, map_budget_s=o.map_budget,
                      frames=o.frames, robot_radius=o.robot_radius, seed=o.seed)
    o.out.mkdir(parents=True, exist_ok=True)
    risk = RiskConfig()
    t_start = time.perf_counter()

    cases = [procedural_case(o.seed * 1000 + i, risk) for i in range(o.scenes)]
    for folder in folders:

        cases.append(make_case(f"scannetpp_{folder.name}", load_scene(folder), risk))
    if not cases:
        raise typer.BadParameter("no scenes: use --scenes ≥ 1 or --scannetpp")
    per_scene = [o.trajectories // len(cases) + (1 if i < o.trajectories % len(cases) else 0)
                 for i in range(len(cases))]


    renderer = Renderer(PinholeCamera.from_fov(*cfg.image, 90.0))
    perceive = gt_perception(renderer) if o.perception == "gt" else sim_perception(renderer, o.seed)
    clf = PointMassCLF(cfg.k_p, cfg.k_d, cfg.v_max, cfg.a_max)
    safe = filter_safe_control(cfg)
    extra = variants(cfg)
    extra_safe = {v.suffix: filter_safe_control(cfg, overrides=v.overrides) for v in extra}
    extra_methods = [f"{m}, {v.suffix}" for m in (ESDF, SEMANTIC) for v in extra]
    per_pair = len(METHODS) + len(extra_methods)
    margins: dict[str, float] = {}

    rollouts: list[Rollout] = []
    maps_info: list[dict] = []
    first_id = 0
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("roll-outs", total=o.trajectories * per_pair)
        for case, n in zip(cases, per_scene, strict=True):
            progress.update(task, description=f"{case.name}: maps")
            snap = case.scene.at(0.0)
            stream = [perceive(snap, T) for T in camera_poses(case, cfg.frames)]
            built = [build_pointcloud(stream, cfg.map_budget_s, cfg.voxel, (case.lo[2], case.hi[2])),
                     *build_esdf_maps(case, stream, cfg.map_budget_s, cfg, risk)]
            for b in built:
                maps_info.append(dict(scene=case.name, method=b.method, frames=b.frames, integrate_s=b.integrate_s,
                                      finalize_s=b.finalize_s, **b.extra))
            pairs = pairs_for(case, n, cfg, first_id)
            first_id += len(pairs)
            if len(pairs) < n:
                console.print(f"[yellow]{case.name}: only {len(pairs)} of {n} pairs could be placed[/yellow]")
                progress.update(task, total=progress.tasks[0].total - (n - len(pairs)) * per_pair)
            progress.update(task, description=f"{case.name}: roll-outs")
            for b in built:
                margins[b.method] = safe.margin_m(b.field)
                if b.method in (ESDF, SEMANTIC):
                    margins.update({f"{b.method}, {k}": c.margin_m(b.field) for k, c in extra_safe.items()})
            for pair in pairs:
                for b in built:
                    rollouts.append(rollout(b.method, pair, b.field, safe, clf, cfg, case))
                    progress.advance(task)
                    if b.method not in (ESDF, SEMANTIC):
                        continue
                    for k, c in extra_safe.items():
                        rollouts.append(rollout(f"{b.method}, {k}", pair, b.field, c, clf, cfg, case))
                        progress.advance(task)

    n_pairs = len({r.pair for r in rollouts})
    mp_all = matched(rollouts, METHODS)
    mp_esdf = matched(rollouts, (ESDF, SEMANTIC))
    t2 = {m: {**summarise(rollouts, mp_all, m).as_dict(), "margin_m": margins[m]} for m in METHODS}
    # Each no-extra-margin row is matched with the other two methods in place of its own.
    counterpart = {f"{m}, {v.suffix}": m for m in (ESDF, SEMANTIC) for v in extra}
    mp_extra: dict = {}
    for m, base in counterpart.items():
        trio = tuple(m if x == base else x for x in METHODS)
        mp_extra.update({k: v for k, v in matched(rollouts, trio).items() if k[0] == m})
    t_extra = {m: {**summarise(rollouts, mp_extra, m).as_dict(), "margin_m": margins[m]} for m in extra_methods}
    methods_info = {m: dict(margin_m=margins[m],
                            barrier=(extra_safe[m.split(", ", 1)[1]] if m in counterpart else safe).barrier,
                            interpolation=(extra_safe[m.split(", ", 1)[1]] if m in counterpart else safe).interpolation,
                            field=counterpart.get(m, m))
                    for m in (*METHODS, *extra_methods)}
    groups = [g.name for g in risk.groups]
    t3 = {g: {"esdf": summarise(rollouts, mp_esdf, ESDF, g).as_dict(),
              "semantic": summarise(rollouts, mp_esdf, SEMANTIC, g).as_dict()} for g in groups}
    t3_all = {"esdf": summarise(rollouts, mp_esdf, ESDF).as_dict(),
              "semantic": summarise(rollouts, mp_esdf, SEMANTIC).as_dict()}
    wall = time.perf_counter() - t_start

    md = [f"# riskfield bench safety — perception `{o.perception}`", "",
          f"{len(cases)} scenes, {n_pairs} matched trajectories, robot radius {o.robot_radius} m, map budget "
          f"{o.map_budget} s, wall time {wall:.0f} s.", "", table2(t2, n_pairs), "", table3(t3, n_pairs), "",
          safety_table({**t2, **t_extra, **{f"{m} – {g}": {**t3[g][k], "margin_m": margins[m]} for g in groups
                                            for m, k in ((ESDF, "esdf"), (SEMANTIC, "semantic"))}}, n_pairs,
                       barrier=safe.barrier), ""]
    (o.out / "tables.md").write_text("\n".join(md))
    per_traj = [dict(pair=r.pair, scene=r.scene, method=r.method, group=r.group, progress=r.progress,
                     reached=r.reached,
                     mp_clearance_all=mp_all.get((r.method, r.pair), mp_extra.get((r.method, r.pair))),
                     mp_clearance_esdf=mp_esdf.get((r.method, r.pair)), min_clearance=r.min_clearance,
                     relaxed_steps=r.relaxed_steps,
                     steps=len(r.filter_times), filter_time_mean_s=float(r.filter_times.mean()),
                     start=r.start, goal=r.goal) for r in rollouts]
    write_json(o.out / "summary.json", dict(
        benchmark="safety", config=cfg.__dict__, risk=risk.model_dump(mode="json"), wall_time_s=wall,
        trajectories=n_pairs, methods=methods_info, table2=t2, no_extra_margin=t_extra, table3=t3,
        table3_overall=t3_all, maps=maps_info,
        filter_time_median_s={m: float(np.median(np.concatenate([r.filter_times for r in rollouts if r.method == m])))
                              for m in (*METHODS, *extra_methods)},
        per_trajectory=per_traj))
    plot_safety(o.out,
                {m: [mp_all[(m, r.pair)] for r in rollouts if r.method == m] for m in METHODS},
                {m: [r.progress for r in rollouts if r.method == m] for m in METHODS},
                {m: np.concatenate([r.filter_times for r in rollouts if r.method == m]) for m in METHODS},
                {g: {"ESDF": [mp_esdf[(ESDF, r.pair)] for r in rollouts if r.method == ESDF and r.group == g],
                     "Semantic": [mp_esdf[(SEMANTIC, r.pair)] for r in rollouts
                                  if r.method == SEMANTIC and r.group == g]} for g in groups})

    table = Table("method", "extra margin (m)", "filter time median (µs)", "p99 (µs)", "progress", "MP clearance (m)",
                  "MP collision", "collision (full run)", "min clearance (m)", "relaxed steps")
    for m in (*METHODS, *extra_methods):
        t = np.concatenate([r.filter_times for r in rollouts if r.method == m]) * 1e6
        row = t2.get(m) or t_extra[m]
        table.add_row(m, f"{margins[m]:.3f}", f"{np.median(t):.0f}", f"{np.percentile(t, 99):.0f}",
                      f"{row['progress']:.3f}",
                      f"{row['mp_clearance_m']:.3f}", f"{row['mp_collision_rate']:.3f}",
                      f"{row['collision_rate']:.3f}", f"{row['min_clearance_m']:.3f}",
                      f"{100 * row['relaxed_fraction']:.2f} %")
    console.print(table)
    g_table = Table("group", "n", "ESDF progress", "ESDF MP clear.", "ESDF MP coll.", "ESDF coll.", "Sem. progress",
                    "Sem. MP clear.", "Sem. MP coll.", "Sem. coll.", "Sem. min clear.")
    for g in groups:
        e, s = t3[g]["esdf"], t3[g]["semantic"]
        g_table.add_row(g, str(e["n"]), *(f"{x:.3f}" for x in (e["progress"], e["mp_clearance_m"],
                                                                e["mp_collision_rate"], e["collision_rate"],
                                                                s["progress"], s["mp_clearance_m"],
                                                                s["mp_collision_rate"], s["collision_rate"],
                                                                s["min_clearance_m"])))
    console.print(g_table)
    console.print(f"wrote {o.out / 'tables.md'}, {o.out / 'summary.json'} and plots ({wall:.0f} s)")


__all__ = ["POINTCLOUD", "app"]
