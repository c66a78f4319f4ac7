"""``riskfield bench teleop``: the paper's teleoperation experiment, in simulation, through the
full service stack over Zenoh.

A LIMO (unicycle, look-ahead safety filter) is driven by the scripted operator service
(``services/operator``: human-like speed, aim, reaction delay and stick noise, one seed per run)
straight at a ball (low risk) and at a dog (ADE20K ``animal``, high risk), ``--runs`` times each.
Simulator → perception (ground-truth relay or the FM-like ``sim`` backend) → mapping →
safety filter → simulator, all separate processes on a loopback router.

Per run: the **first intervention distance** (ground-truth distance from the look-ahead point
to the obstacle surface when ``SafetyStatus`` first reports a CBF intervention) and the
**minimum clearance** (smallest such distance over the run); the robot-centre distances too.
The look-ahead distance is what the filter constrains (the paper's plotted ``d(p_L)``).

``--preset paper`` runs the filter node with the shipped ``paper`` preset
(``safety_filter/presets/paper.yaml``: the look-ahead point only, no body discs, no robot radius or
extra margin, no predictive rows, the trilinear field — the paper's filter); the default is the
product's filter (LIMO body discs, radius 0.15 m, δ + half a voxel: about 0.2 m beyond d(p_L)).
Outputs: ``summary.json``, ``tables.md`` beside the paper's numbers, ``teleop.png`` (distance,
linear and angular velocity over time for one run of each class).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from riskfield.experiments.scenarios import TELEOP_CASES, obstacle_distance
from riskfield.experiments.stack import FAST_FILTER, Stack, perception_args, recording
from riskfield.experiments.tables import write_json
from riskfield.experiments.teleop import PAPER, Trace, operator_args, trace_of
from riskfield.protocol import RobotState, SafetyStatus, VelocityCommand

app = typer.Typer(add_completion=False)


def filter_args(preset: str | None) -> list[str]:
    """The filter node's arguments: the bench's rate, and the preset when one is named."""
    return [*FAST_FILTER, *(["--set", f"preset={preset}"] if preset else [])]


def run_class(stack: Stack, cls: str, runs: int, run_s: float, perception: str, progress, task,
              preset: str | None = None) -> list[Trace]:
    scenario, obj = TELEOP_CASES[cls]
    distance = obstacle_distance(scenario, obj)
    service, args = perception_args(perception)
    stack.start("perception", service, args)
    stack.start("mapping", "mapping", ["--set", "esdf_rate_hz=10"])
    stack.start("filter", "safety-filter", filter_args(preset))
    traces = []
    k = stack.keys
    keys = {"state": (k.state, RobotState), "ref": (k.cmd_ref_any, VelocityCommand),
            "safe": (k.cmd_safe, VelocityCommand), "status": (k.safety_status, SafetyStatus)}
    for run in range(runs):
        stack.start("sim", "simulator", ["--set", f"scenario={scenario}", "--set", "camera_hz=10"])
        with recording(stack.session, keys) as rec:
            time.sleep(1.5)  # the first frames reach the map before the operator starts
            rec.clear()
            t0 = time.monotonic()
            stack.start("operator", "operator", operator_args([(obj, 0.5, 0.0)], seed=run, push_s=10.0))
            time.sleep(run_s)
            stack.stop("operator")
            traces.append(trace_of(rec, distance, t0))
        stack.stop("sim")
        progress.advance(task)
    for label in ("filter", "mapping", "perception"):
        stack.stop(label)
    return traces


def plot(out: Path, examples: dict[str, Trace]) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(len(examples), 3, figsize=(13, 3.2 * len(examples)), squeeze=False)
    for row, (cls, tr) in enumerate(examples.items()):
        ax[row, 0].plot(tr.t, tr.lookahead_distance, label="look-ahead point")
        ax[row, 0].plot(tr.t, tr.centre_distance, "--", label="robot centre")
        if tr.t_intervention is not None:
            for a in ax[row]:
                a.axvline(tr.t_intervention, color="r", lw=0.8, ls=":")
        ax[row, 0].set_ylabel(f"{cls}\nobstacle distance (m)")
        ax[row, 1].plot(tr.t_cmd, tr.v_ref, label="operator")
        ax[row, 1].plot(tr.t_safe, tr.v_safe, label="filtered")
        ax[row, 1].set_ylabel("linear velocity (m/s)")
        ax[row, 2].plot(tr.t_cmd, tr.w_ref, label="operator")
        ax[row, 2].plot(tr.t_safe, tr.w_safe, label="filtered")
        ax[row, 2].set_ylabel("angular velocity (rad/s)")
        for a in ax[row]:
            a.set_xlabel("time (s)")
            a.legend(fontsize=7)
    fig.tight_layout()
    path = out / "teleop.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _mean(xs: list[float | None]) -> float:
    vals = [x for x in xs if x is not None and math.isfinite(x)]
    return float(np.mean(vals)) if vals else float("nan")


@app.command()
def teleop(
    runs: Annotated[int, typer.Option(help="Runs per obstacle class (paper: 12).")] = 12,
    perception: Annotated[str, typer.Option(help="gt or sim.")] = "gt",
    run_s: Annotated[float, typer.Option(help="Seconds each run lasts after the operator starts.")] = 13.0,
    classes: Annotated[str, typer.Option(help="Comma-separated: ball,dog.")] = "ball,dog",
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("bench_out/teleop"),
    preset: Annotated[str | None, typer.Option(
        help="Filter preset (safety_filter/presets): paper = the paper's look-ahead filter; none = the product's.")]
    = None,
) -> None:
    """Scripted-operator teleoperation towards a ball and a dog through the full stack."""
    console = Console()
    names = [c.strip() for c in classes.split(",") if c.strip()]
    if not names or any(c not in TELEOP_CASES for c in names):
        raise typer.BadParameter(f"classes must be among {', '.join(TELEOP_CASES)}")
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    results: dict[str, list[Trace]] = {}
    with Progress(console=console) as progress:
        task = progress.add_task("teleop runs", total=runs * len(names))
        for cls in names:
            with Stack(robot=f"teleop_{cls}") as stack:
                results[cls] = run_class(stack, cls, runs, run_s, perception, progress, task, preset)
    summary: dict[str, dict] = {}
    table = Table("class", "runs", "first intervention (m)", "paper", "min clearance (m)", "paper",
                  "runs with intervention")
    which = (f"the `{preset}` preset (`services/safety_filter/presets/{preset}.yaml`)" if preset else
             "the product's default filter (LIMO body discs, robot radius 0.15 m, δ + half a voxel)")
    md = [f"# riskfield bench teleop — perception `{perception}`" + (f", preset `{preset}`" if preset else ""), "",
          f"Filter: {which}. Distances: ground truth, look-ahead point (L = 0.25 m) to the obstacle surface; "
          "mean over runs.", "",
          "| Obstacle | Runs | First intervention (m) | Paper | Min clearance (m) | Paper | Centre: first / min (m) |",
          "|---|---|---|---|---|---|---|"]
    for cls, traces in results.items():
        ms = [tr.metrics() for tr in traces]
        first = _mean([m["first_intervention_m"] for m in ms])
        clear = _mean([m["min_clearance_m"] for m in ms])
        first_c = _mean([m["first_intervention_centre_m"] for m in ms])
        clear_c = _mean([m["min_clearance_centre_m"] for m in ms])
        n_int = sum(m["first_intervention_m"] is not None for m in ms)
        summary[cls] = dict(runs=len(ms), first_intervention_m=first, min_clearance_m=clear,
                            first_intervention_centre_m=first_c, min_clearance_centre_m=clear_c,
                            runs_with_intervention=n_int, per_run=ms, paper=PAPER[cls])
        table.add_row(cls, str(len(ms)), f"{first:.3f}", f"{PAPER[cls]['first_intervention_m']:.2f}", f"{clear:.3f}",
                      f"{PAPER[cls]['min_clearance_m']:.2f}", str(n_int))
        md.append(f"| {cls} | {len(ms)} | {first:.3f} | {PAPER[cls]['first_intervention_m']:.2f} | {clear:.3f} | "
                  f"{PAPER[cls]['min_clearance_m']:.2f} | {first_c:.3f} / {clear_c:.3f} |")
    examples = {cls: traces[0] for cls, traces in results.items() if traces}
    plot(out, examples)
    wall = time.perf_counter() - t_start
    (out / "tables.md").write_text("\n".join(md) + "\n")
    write_json(out / "summary.json", dict(benchmark="teleop", perception=perception, preset=preset, runs=runs,
                                          run_s=run_s,
                                          wall_time_s=wall, classes=summary,
                                          examples={c: {k: getattr(tr, k) for k in tr.__dataclass_fields__}
                                                    for c, tr in examples.items()}))
    console.print(table)
    console.print(f"wrote {out / 'tables.md'}, {out / 'summary.json'}, {out / 'teleop.png'} ({wall:.0f} s)")
