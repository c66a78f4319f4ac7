"""``riskfield bench filter``: per-step cost of the safety filter, per model and QP solver.

For each barrier model a grid ESDF of a small scene (a high-risk and a low-risk obstacle and a
wall; a 2-D slice for the ground models, 3-D otherwise) is queried from random states close to
the obstacles with random references, so that most steps intervene. A step is the whole
``SafetyFilter.filter`` call: field query (distance, gradient, Hessian for the HOCBF) at the
barrier points and their predicted positions, CBF rows, and the QP — once with the exact
active-set path and once with OSQP. Reports median and p99 (µs) and writes ``summary.json``.
"""

from __future__ import annotations

import json
import math
import platform
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from riskfield.services.fields import AnalyticField, to_esdf
from riskfield.services.geometry.shapes import Plane, Sphere
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.state import FilterState, so3_exp

app = typer.Typer(add_completion=False)

MODELS = ("unicycle", "single2d", "single3d", "double3d")
GROUPS = ["high", "mid", "low"]


def scene(planar: bool) -> AnalyticField:
    return AnalyticField([
        Sphere((1.0, 0.0, 0.0), 0.3, label=1, planar=planar),
        Sphere((0.95, 0.75, 0.0), 0.25, label=3, planar=planar),
        Plane.through((0.0, -0.7, 0.0), (0.0, 1.0, 0.0), label=2),
    ], groups=GROUPS)


def _cases(filt: SafetyFilter, field, planar: bool, n: int, rng: np.random.Generator) -> list:
    model = filt.model
    cases = []
    while len(cases) < n:
        p = rng.uniform([-0.3, -0.6, -0.3], [2.0, 1.4, 0.3])
        if planar:
            p[2] = 0.0
            s = FilterState.planar(p[0], p[1], rng.uniform(-math.pi, math.pi), velocity=tuple(rng.normal(0, 0.3, 3)))
        else:
            s = FilterState(p, so3_exp(rng.normal(0, 0.5, 3)), rng.normal(0, 0.3, 3))
        d = field.query(model.points(s)).distance - model.radius
        if not 0.0 <= d.min() <= 0.6:
            continue
        u_ref = rng.uniform(model.lo, model.hi)
        cases.append((s, u_ref, rng.normal(0, 0.5, 3)))
    return cases


def _stats(x: list[float]) -> dict[str, float]:
    a = np.asarray(x)
    return {"median": float(np.median(a)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}


@app.command()
def main(
    out: Annotated[Path, typer.Option(help="Folder for summary.json.")] = Path("out/bench-filter"),
    steps: Annotated[int, typer.Option(help="Filter steps per model and solver.")] = 3000,
    voxel: Annotated[float, typer.Option(help="ESDF voxel size (m).")] = 0.05,
    seed: Annotated[int, typer.Option()] = 0,
) -> None:
    """Time the safety filter per step (field query + QP) for each model, OSQP vs the exact path."""
    console = Console(width=140)
    rng = np.random.default_rng(seed)
    results: dict[str, dict] = {}
    for name in MODELS:
        planar = name in ("unicycle", "single2d")
        grid = to_esdf(scene(planar), [-1.0, -1.0, 0.0 if planar else -0.6], [3.0, 2.0, 0.0 if planar else 0.6],
                       voxel, planar=planar)
        probe = SafetyFilter(FilterConfig(model=name))
        cases = _cases(probe, grid, planar, steps, rng)
        pts = [probe.model.points(s) for s, _, _ in cases]
        hess = probe.model.needs_hessian
        query_us = []
        for p in pts:
            t0 = time.perf_counter()
            grid.query(p, hessian=hess)
            query_us.append((time.perf_counter() - t0) * 1e6)
        for solver in ("active_set", "osqp"):
            filt = SafetyFilter(FilterConfig(model=name, solver=solver))
            step_us, qp_us, hits, fallbacks = [], [], 0, 0
            for _ in range(2):  # the first pass warms caches and OSQP's warm start
                step_us, qp_us, hits, fallbacks = [], [], 0, 0
                for s, u_ref, ang in cases:
                    t0 = time.perf_counter()
                    res = filt.filter(s, u_ref, grid, ang)
                    step_us.append((time.perf_counter() - t0) * 1e6)
                    qp_us.append(res.qp_us)
                    hits += res.intervening and res.fallback is None
                    fallbacks += res.fallback is not None
            results[f"{name}/{solver}"] = {
                "model": name, "solver": solver, "steps": len(cases), "step_us": _stats(step_us),
                "qp_us": _stats(qp_us), "field_query_us": _stats(query_us),
                "intervening_fraction": hits / len(cases), "fallback_fraction": fallbacks / len(cases),
            }
    table = Table(title=f"safety filter per step (µs), {steps} steps per row, voxel {voxel} m")
    for col in ("model", "solver", "step p50", "step p99", "QP p50", "QP p99", "query p50", "intervening"):
        table.add_column(col, justify="right" if col not in ("model", "solver") else "left")
    for r in results.values():
        table.add_row(r["model"], r["solver"], f"{r['step_us']['median']:.1f}", f"{r['step_us']['p99']:.1f}",
                      f"{r['qp_us']['median']:.1f}", f"{r['qp_us']['p99']:.1f}",
                      f"{r['field_query_us']['median']:.1f}", f"{100 * r['intervening_fraction']:.0f} %")
    console.print(table)
    out.mkdir(parents=True, exist_ok=True)
    summary = {"benchmark": "filter", "python": platform.python_version(), "machine": platform.machine(),
               "steps": steps, "voxel_size": voxel, "results": results}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    console.print(f"wrote {out / 'summary.json'}")
