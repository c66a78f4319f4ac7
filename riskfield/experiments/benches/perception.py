"""``riskfield bench perception``: cost of the sim backend per frame (degradation, matching,
eq. (2) and vote fusion), of its fusion kernel alone and of the vote rule the ``mast3r`` backend
runs, and the ``rgbd`` backend's rate (depth → pointmap, odometry pose, one class; plus the message
encoding a node adds), at 512×384."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from riskfield.experiments.timing import timing_stats
from riskfield.protocol import DepthImage, Image, PerceptionFrame, RobotState, encode
from riskfield.protocol.messages import Header
from riskfield.services.perception import kernels
from riskfield.services.perception.fusion import vote_fuse
from riskfield.services.perception.rgbd_backend import RgbdBackend
from riskfield.services.perception.sim_backend import SimBackend, SimBackendConfig
from riskfield.services.simulator.world import World

app = typer.Typer(add_completion=False)


@app.command()
def perception(out: Annotated[Path, typer.Option(help="Folder for summary.json.")] = Path("out/bench-perception"),
               n: Annotated[int, typer.Option(help="Frames per measurement.")] = 60) -> None:
    """Sim backend per frame (both publish modes) and the fusion rules, on a driving sequence."""

    world = World("navigation")
    truths, rgbd = [], []
    cam = world.camera
    for i in range(n):
        world.command(np.array([0.4, 0, 0]), np.array([0, 0, 0.3]))
        world.advance(0.1)
        r = world.render()
        truths.append(PerceptionFrame(T_WC=r.T_WC, points=r.points, confidence=r.valid.astype(np.float32),
                                      labels=r.labels, keyframe_id=i))
        st = world.state()
        rgbd.append((Image(encoding="rgb8", width=cam.width, height=cam.height, data=r.rgb),
                     DepthImage(depth=r.depth, fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy),
                     RobotState(header=Header(stamp_ns=i), position=tuple(st.position),
                                orientation=tuple(st.orientation), linear_velocity=(0, 0, 0),
                                angular_velocity=(0, 0, 0))))
    results: dict[str, dict[str, float]] = {}
    extra: dict[str, float] = {}
    for mode in ("keyframe", "frame"):
        b = SimBackend(SimBackendConfig(publish=mode))
        ts = []
        for i, t in enumerate(truths):
            t0 = time.perf_counter()
            b.process(None, t, i)
            ts.append((time.perf_counter() - t0) * 1e3)
        results[f"sim backend per frame ({mode})"] = timing_stats(ts)
        extra[f"keyframes_{mode}"] = b.n_keyframes
    rb = RgbdBackend()
    ts, ts_enc = [], []
    for i, (img, depth, state) in enumerate(rgbd):
        t0 = time.perf_counter()
        rb.on_state(state)
        (frame,) = rb.process(img, depth, i)
        t1 = time.perf_counter()
        encode(frame)
        ts.append((t1 - t0) * 1e3)
        ts_enc.append((time.perf_counter() - t0) * 1e3)
    results["rgbd backend per frame"] = timing_stats(ts)
    results["rgbd backend + encoding per frame"] = timing_stats(ts_enc)
    extra["rgbd_rate_hz"] = 1e3 / results["rgbd backend + encoding per frame"]["median"]
    rng = np.random.default_rng(0)
    N = 512 * 384
    X, C = rng.normal(size=(N, 3)).astype(np.float32), np.ones(N, np.float32)
    L, W = rng.integers(0, 150, N).astype(np.uint16), np.ones(N, np.float32)
    mask, q = rng.random(N) < 0.8, rng.uniform(1, 3, N)
    frame, matches = (X, C, L[::-1].copy()), (np.arange(N, dtype=np.int64), mask, q)
    fused = (np.empty_like(X), np.empty_like(C), np.empty_like(L), np.empty_like(W), np.empty(N, bool))

    def fuse() -> None:  # eq. (2) and (7)-(8) in one pass, the sim backend's kernel
        kernels.fuse_kernel(np.eye(4), frame, matches, 1.5, (X, C, L, W), fused)

    fuse()  # loaded (or compiled) before it is timed
    for name, fn in (("keyframe fusion kernel, 512x384", fuse),
                     ("vote fusion (mast3r backend), 512x384", lambda: vote_fuse(L, W, L[::-1].copy(), q, mask))):
        ts = []
        for _ in range(n):
            t0 = time.perf_counter()
            fn()
            ts.append((time.perf_counter() - t0) * 1e3)
        results[name] = timing_stats(ts)
    table = Table("operation", "median ms", "p99 ms", "max ms", "n", title="riskfield bench perception")
    for k, v in results.items():
        table.add_row(k, f"{v['median']:.2f}", f"{v['p99']:.2f}", f"{v['max']:.2f}", str(int(v["n"])))
    Console().print(table)
    Console().print(f"rgbd backend rate: {extra['rgbd_rate_hz']:.0f} frames/s (median, one core, with encoding)")
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps({"bench": "perception", "results": results, **extra}, indent=2) + "\n")


if __name__ == "__main__":
    app()
