"""``riskfield bench safety --protocol authors``: the paper's published protocol (``authors``).

Writes ``tables.md`` (Table II with full-run columns, Table III per semantic mode, the paper's
tables beside them, counts per scene and group) and ``summary.json`` (every number and every
trajectory) into ``out``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from riskfield.experiments import authors as A
from riskfield.experiments import authors_bench as B
from riskfield.experiments.safety_benchmark import BenchConfig, gt_perception, sim_perception
from riskfield.experiments.scannetpp import load_scene
from riskfield.experiments.tables import authors_tables, write_json
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.simulator.camera import Renderer
from riskfield.services.simulator.procedural import random_room


def procedural_scene(seed: int) -> B.Scene:
    """The riskfield protocol's procedural room (every mesh object carries its ADE20K class)."""
    return B.Scene(f"procedural_{seed}", random_room(seed, furniture=4, boxes=2, balls=2, people=2, animals=2))


def authors_run(out: Path, *, scenes: int, folders: Sequence[Path], perception: str, per_group: int = 50,
                options: B.RunOptions, console: Console | None = None) -> dict:
    """The protocol over ``scenes`` procedural rooms and the ScanNet++ ``folders``, ``per_group``
    start/goal pairs requested per risk group and scene, with ``perception`` gt or sim; writes
    ``out``'s files (module doc) and returns the summary."""
    console = console or Console()
    seed, modes, map_budget = options.seed, options.modes, options.map_budget_s
    t_start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    cfg = A.AuthorsConfig(per_group=per_group)
    todo = [procedural_scene(seed * 1000 + i) for i in range(scenes)]
    todo += [B.Scene(f"scannetpp_{f.name}", load_scene(f)) for f in folders]
    if not todo:
        raise ValueError("no scenes: use --scenes ≥ 1 or --scannetpp")
    renderer = Renderer(PinholeCamera.from_fov(*BenchConfig().image, 90.0))
    perceive = gt_perception(renderer) if perception == "gt" else sim_perception(renderer, seed)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("scenes", total=0)

        def on_scene(description: str, more: int) -> None:
            progress.update(task, description=description, total=progress.tasks[0].total + more)

        result = B.run(todo, perceive, cfg, options, on_scene=on_scene, on_rollout=lambda: progress.advance(task))
    primary = modes[0]
    t = B.tables(result, primary)
    wall = time.perf_counter() - t_start
    trio = [m for m in (B.BASELINE, B.ESDF, B.SEMANTIC[primary]) if m in t["table2"]]
    md = [f"# riskfield bench safety --protocol authors — perception `{perception}`", "",
          f"{len(todo)} scenes, {t['trajectories']} trajectories accepted of {3 * per_group * len(todo)} requested "
          f"(groups {t['groups']['high']}/{t['groups']['mid']}/{t['groups']['low']}), radius {cfg.radius} m, "
          f"α = {cfg.alpha}, β = {cfg.beta}, {cfg.steps} steps of {cfg.dt} s, map budget {map_budget} s, "
          f"wall time {wall:.0f} s.", "", authors_tables(t, primary, trio), ""]
    (out / "tables.md").write_text("\n".join(md))
    summary = dict(benchmark="safety", protocol="authors", perception=perception, semantic_modes=list(modes),
                   primary_semantic_mode=primary, config=cfg.__dict__, wall_time_s=wall, scenes=result.scenes,
                   **t, per_trajectory=B.per_trajectory(result, primary))
    write_json(out / "summary.json", summary)

    table = Table("method", "time (ms)", "progress", "MP clearance (m)", "MP collision", "collision (full)",
                  "min clearance, mean (m)", "min clearance, min (m)")
    for m, r in t["table2"].items():
        table.add_row(m, f"{1e3 * r['computation_time_s']:.3f}", f"{r['progress']:.3f}", f"{r['mp_clearance_m']:.3f}",
                      f"{r['mp_collision_rate']:.3f}", f"{r['collision_rate']:.3f}",
                      f"{r['min_clearance_mean_m']:.3f}", f"{r['min_clearance_m']:.3f}")
    console.print(table)
    console.print(f"groups {t['groups']}; wrote {out / 'tables.md'} and {out / 'summary.json'} ({wall:.0f} s)")
    return summary
