"""``riskfield bench scale``: stopping at a wall 1–4 m ahead through a SLAM of scale s, drifting.

Each scale in ``--scales`` × each distance in ``--distances``, twice: ``aligned`` (perception's
online SLAM → odometry estimate, the filter's shrunk distance and speed cap) and ``anchored`` (SLAM's
world placed once at the first image, as before). The loop, the errors and every metric are
``riskfield.experiments.scale_core``'s. Outputs ``summary.json`` and ``tables.md``; ``--results``
rewrites that RESULTS.md's ``Map scale`` section (between ``<!-- scale:begin -->`` and ``<!-- scale:end -->``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from riskfield.experiments import scale_core as C
from riskfield.experiments.tables import write_json

app = typer.Typer(add_completion=False)


def _floats(text: str, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError as exc:
        raise typer.BadParameter(f"{what}: {exc}") from exc
    if not values or any(v <= 0 for v in values):
        raise typer.BadParameter(f"{what}: positive numbers, comma-separated")
    return values


@app.command()
def scale(
    scales: Annotated[str, typer.Option(help="SLAM scale factors s, comma-separated.")] = ",".join(
        f"{s:g}" for s in C.SCALES),
    distances: Annotated[str, typer.Option(help="Wall distances ahead of the camera (m), comma-separated.")] =
    ",".join(f"{d:g}" for d in C.DISTANCES),
    seed: Annotated[int, typer.Option(help="Seed of the SLAM drift, the noise and the slip.")] = 0,
    drift: Annotated[bool, typer.Option(help="Scale and heading drift and odometry slip on.")] = True,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("bench_out/scale"),
    results: Annotated[Path | None, typer.Option(help="Rewrite this RESULTS.md's 'Map scale' section.")] = None,
    mode: Annotated[str, typer.Option(help="core: the closed loop in one process (scale_core); stack: simulator, "
                                      "perception, mapping and filter as processes, at one distance.")] = "core",
    stack_distance: Annotated[float, typer.Option(help="stack: the wall's distance ahead of the camera (m).")] = 2.5,
) -> None:
    """A wall 1–4 m ahead, SLAM's scale wrong by s: where the map puts it, and where the robot stops."""
    console = Console()
    sc, ds = _floats(scales, "scales"), _floats(distances, "distances")
    if 1.0 not in sc:
        raise typer.BadParameter("scales must include 1 (the reference run)")
    out.mkdir(parents=True, exist_ok=True)
    if mode == "stack":
        t0 = time.perf_counter()
        rows = C.run_stack(sc, stack_distance, out, drift, seed)
        summary = {"benchmark": "scale", "mode": "stack", "rows": rows, "wall_s": time.perf_counter() - t0}
        (out / "tables.md").write_text("\n".join(C.stack_section_body(summary)) + "\n")
        write_json(out / "summary.json", summary)
        console.print("\n".join(C.stack_section_body(summary)[:-2]))
        if results is not None:
            C.update_results(results, summary)
            console.print(f"rewrote the stack scale section of {results}")
        return
    if mode != "core":
        raise typer.BadParameter("mode must be core or stack")
    t0 = time.perf_counter()
    rows = C.run_all(sc, ds, seed, drift)
    summary = {"benchmark": "scale", **C.summarise(rows, time.perf_counter() - t0)}
    (out / "tables.md").write_text("\n".join(C.section_body(summary)) + "\n")
    write_json(out / "summary.json", summary)
    console.print(C.table(summary))
    gap_ok, err_ok = ("met" if summary[k] else "MISSED" for k in ("gap_target_met", "error_target_met"))
    console.print(f"worst aligned gap − s=1: {C._f(summary['worst_gap_vs_s1'])} m ({gap_ok}); worst error at 3 m "
                  f"after 1 m: {C._f(summary['worst_error_3m_after_1m'])} m ({err_ok})")
    if results is not None:
        C.update_results(results, summary)
        console.print(f"rewrote the scale section of {results}")
    console.print(f"wrote {out / 'tables.md'} and {out / 'summary.json'} ({summary['wall_s']:.0f} s)")
