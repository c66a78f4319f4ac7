"""``riskfield bench sim``: what the simulator costs per camera frame and per physics step.

Measures, on the built-in ``navigation`` scenario: ray-cast rendering (RGB, pointmap, labels) at
512×384 and 640×480, rebuilding the raycasting scene when an object moved, ground-truth signed
distance queries, a physics step, and encoding the image and ground-truth messages.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from riskfield.experiments.timing import timing_stats
from riskfield.protocol import Image, PerceptionFrame, encode
from riskfield.services.simulator.scenario import load_scenario
from riskfield.services.simulator.scene import Scene
from riskfield.services.simulator.world import World

app = typer.Typer(add_completion=False)

#: One ray from the origin along +x, packed as open3d takes it (origin, direction).
RAY = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]], np.float32)


def _time(fn: Callable[[], object], n: int) -> dict[str, float]:
    fn()  # warm-up
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return timing_stats(ts)


@app.command()
def sim(out: Annotated[Path, typer.Option(help="Folder for summary.json.")] = Path("out/bench-sim"),
        n: Annotated[int, typer.Option(help="Repetitions per measurement.")] = 50) -> None:
    """Render, scene rebuild, signed distance, physics and message encoding times."""
    results: dict[str, dict[str, float]] = {}
    for w, h in ((512, 384), (640, 480)):
        sc = load_scenario("navigation").model_copy(deep=True)
        sc.camera.width, sc.camera.height = w, h
        world = World(sc)
        world.snapshot()
        results[f"render {w}x{h}"] = _time(world.render, n)
    world = World("navigation")
    moving = [o for o in world.scene.objects if o.moving]
    t = [0.0]

    def rebuild() -> None:
        t[0] += 0.1  # the walker moved: a new raycasting scene (its BVH is built on the first query)
        world.scene.at(t[0]).cast_packed(RAY)

    results["scene rebuild + first ray (moving object)"] = _time(rebuild, n)
    pts = np.random.default_rng(0).uniform([-3.5, -3.5, 0], [3.5, 3.5, 2.5], (10_000, 3))
    snap = Scene(world.scene.objects).at(0.0)
    results["signed distance, 10k points"] = _time(lambda: snap.signed_distance(pts), n)
    results["physics step (limo)"] = _time(lambda: world.advance(world.physics_dt), n * 20)
    frame = world.render()
    img = Image(encoding="rgb8", width=frame.rgb.shape[1], height=frame.rgb.shape[0], data=frame.rgb)
    results["encode Image 512x384"] = _time(lambda: encode(img), n)
    truth = PerceptionFrame(T_WC=frame.T_WC, points=frame.points, confidence=frame.valid.astype(np.float32),
                            labels=frame.labels, keyframe_id=0)
    results["build+encode truth 512x384"] = _time(
        lambda: encode(PerceptionFrame(T_WC=frame.T_WC, points=frame.points, confidence=frame.valid.astype(np.float32),
                                       labels=frame.labels, keyframe_id=0)), n)
    del truth
    summary = {"bench": "sim", "scenario": "navigation", "moving_objects": len(moving), "results": results}
    table = Table("operation", "median ms", "p99 ms", "max ms", "n", title="riskfield bench sim")
    for k, v in results.items():
        table.add_row(k, f"{v['median']:.2f}", f"{v['p99']:.2f}", f"{v['max']:.2f}", str(int(v["n"])))
    Console().print(table)
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    app()
