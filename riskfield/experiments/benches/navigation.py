"""``riskfield bench navigation``: the paper's loop experiment through the full service stack.

A LIMO in a 7 × 7 m room (a table in the middle, a chair and a ball near the path) is sent
round the four corners of a 4 m square by the navigator (CLF nominal controller), the safety
filter correcting it on the live semantic ESDF. Lap 1 runs in the room as mapped on the way;
then an unseen obstacle (a ball, as in the paper) is spawned on the path and lap 2 runs with
the same waypoints. Per lap: completion (every corner reached before ``--lap-timeout``), lap
time, deviation from the nominal square (max and mean distance to it) and the minimum
ground-truth clearance (robot centre to the nearest obstacle surface). Outputs
``summary.json``, ``tables.md`` and ``navigation.png`` (overhead view of both laps).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
import yaml
from rich.console import Console
from rich.table import Table

from riskfield.experiments.navigation import drive, place_unseen, polyline_distance
from riskfield.experiments.scenarios import SQUARE_CORNERS, SQUARE_ROOM, SQUARE_UNSEEN, risky_clearance
from riskfield.experiments.stack import FAST_FILTER, Stack, perception_args, recording
from riskfield.experiments.tables import write_json
from riskfield.experiments.teleop import is_intervention
from riskfield.protocol import RobotState, SafetyStatus

app = typer.Typer(add_completion=False)

TOLERANCE = 0.2


def run_lap(stack: Stack, rec, timeout_s: float) -> dict:
    """Send the square once and wait until the last corner is reached (or the timeout)."""
    rec.clear()
    lap = drive(stack.session, stack.keys, rec, SQUARE_CORNERS, TOLERANCE, timeout_s)
    states = rec.snapshot("state")
    status = rec.snapshot("status")
    path = np.array([st.position for _, st in states]).reshape(-1, 3)
    return dict(completed=lap.completed, reached=lap.reached, lap_time_s=lap.lap_time_s,
                path=path, interventions=sum(1 for _, s in status if is_intervention(s)),
                brakes=sum(1 for _, s in status if s.fallback is not None), steps=len(status))


def plot(out: Path, laps: list[dict], unseen: dict) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    fig, axes = plt.subplots(1, len(laps), figsize=(5.5 * len(laps), 5.2), squeeze=False)
    for ax, lap, title in zip(axes[0], laps, ("lap 1: loop on the live map", "lap 2: unseen obstacle"),
                              strict=False):
        sq = np.vstack([SQUARE_CORNERS, SQUARE_CORNERS[:1]])
        ax.plot(sq[:, 0], sq[:, 1], "k--", lw=0.8, label="nominal square")
        ax.add_patch(Rectangle((-0.6, -0.35), 1.2, 0.7, color="tab:brown", alpha=0.4, label="table"))
        ax.add_patch(Rectangle((2.8 - 0.225, -0.225), 0.45, 0.45, color="tab:olive", alpha=0.4, label="chair"))
        ax.add_patch(Circle((0.0, 2.6), 0.12, color="tab:orange", alpha=0.6, label="ball"))
        if lap is laps[-1] and len(laps) > 1:
            ax.add_patch(Circle(tuple(unseen["position"]), 0.12, color="tab:red", alpha=0.8, label="unseen ball"))
        p = lap["path"]
        if len(p):
            ax.plot(p[:, 0], p[:, 1], "tab:blue", lw=1.5, label="robot")
            ax.plot(p[0, 0], p[0, 1], "go")
        ax.set_aspect("equal")
        ax.set_xlim(-3.5, 3.5)
        ax.set_ylim(-3.5, 3.5)
        ax.set_title(title)
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    path = out / "navigation.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


@app.command()
def navigation(
    perception: Annotated[str, typer.Option(help="gt or sim.")] = "gt",
    lap_timeout: Annotated[float, typer.Option(help="Seconds allowed per lap.")] = 120.0,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("bench_out/navigation"),
) -> None:
    """Loop of four corners with the navigator, then again with an unseen obstacle on the path."""
    console = Console()
    out.mkdir(parents=True, exist_ok=True)
    scenario_path = out / "navigation_scenario.yaml"
    scenario_path.write_text(yaml.safe_dump(SQUARE_ROOM))
    t_start = time.perf_counter()
    with Stack(robot="nav_loop") as stack:
        keys = {"state": (stack.keys.state, RobotState), "status": (stack.keys.safety_status, SafetyStatus)}
        service, args = perception_args(perception)
        stack.start("sim", "simulator", ["--set", f"scenario={scenario_path}", "--set", "camera_hz=10"])
        stack.start("perception", service, args)
        stack.start("mapping", "mapping", ["--set", "esdf_rate_hz=10"])
        stack.start("filter", "safety-filter", FAST_FILTER)
        stack.start("navigator", "navigator", ["--set", "rate_hz=20", "--set", "stop_hold_s=2"])
        laps = []
        with recording(stack.session, keys) as rec:
            time.sleep(2.0)  # first frames into the map
            laps.append(run_lap(stack, rec, lap_timeout))
            place_unseen(stack.session, stack.keys, SQUARE_UNSEEN)
            time.sleep(2.5)  # the navigator's stop hold ends; the new obstacle is in view of nothing yet
            laps.append(run_lap(stack, rec, lap_timeout))
    clearance = risky_clearance(scenario_path, [SQUARE_UNSEEN])
    base_clear = risky_clearance(scenario_path)
    rows = []
    for i, lap in enumerate(laps):
        p = lap["path"]
        dev = polyline_distance(p, SQUARE_CORNERS) if len(p) else np.zeros(1)
        clear = (clearance if i == 1 else base_clear)(p[:, :2]) if len(p) else np.zeros(1)
        near = np.linalg.norm(p[:, :2] - np.array(SQUARE_UNSEEN["position"]), axis=1) if len(p) else np.zeros(1)
        lap.update(max_deviation_m=float(dev.max()), mean_deviation_m=float(dev.mean()),
                   min_clearance_m=float(clear.min()),
                   closest_to_unseen_m=float(near.min()) if i == 1 else None)
        rows.append(lap)
    plot(out, laps, SQUARE_UNSEEN)
    wall = time.perf_counter() - t_start
    md = [f"# riskfield bench navigation — perception `{perception}`", "",
          "Square of four corners (4 m side), tolerance 0.2 m; clearance: robot centre to the nearest obstacle "
          "surface (ground truth).", "",
          "| Lap | Completed | Corners reached | Lap time (s) | Max deviation (m) | Mean deviation (m) | "
          "Min clearance (m) | CBF interventions (steps) |", "|---|---|---|---|---|---|---|---|"]
    table = Table("lap", "completed", "time (s)", "max dev. (m)", "mean dev. (m)", "min clearance (m)",
                  "interventions")
    for i, lap in enumerate(rows, start=1):
        t = "–" if lap["lap_time_s"] is None else f"{lap['lap_time_s']:.1f}"
        md.append(f"| {i}{' (unseen ball)' if i == 2 else ''} | {lap['completed']} | {lap['reached']}/4 | {t} | "
                  f"{lap['max_deviation_m']:.3f} | {lap['mean_deviation_m']:.3f} | {lap['min_clearance_m']:.3f} | "
                  f"{lap['interventions']} |")
        table.add_row(str(i), str(lap["completed"]), t, f"{lap['max_deviation_m']:.3f}",
                      f"{lap['mean_deviation_m']:.3f}", f"{lap['min_clearance_m']:.3f}", str(lap["interventions"]))
    md += ["", "Paper (hardware): both laps completed; in lap 2 the robot deviates around the unseen ball and "
           "returns to the loop (no numbers reported)."]
    (out / "tables.md").write_text("\n".join(md) + "\n")
    write_json(out / "summary.json", dict(benchmark="navigation", perception=perception, wall_time_s=wall,
                                          corners=SQUARE_CORNERS, unseen=SQUARE_UNSEEN, laps=rows))
    console.print(table)
    console.print(f"wrote {out / 'tables.md'}, {out / 'summary.json'}, {out / 'navigation.png'} ({wall:.0f} s)")
