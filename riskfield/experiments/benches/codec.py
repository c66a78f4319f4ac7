"""``riskfield bench codec``: what the wire costs — encode/decode of the big messages, and a
Zenoh round trip between two processes through the embedded router on loopback."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from riskfield.experiments.timing import timing_stats
from riskfield.protocol import EsdfGrid, PerceptionFrame, VelocityCommand, decode, encode

app = typer.Typer(add_completion=False)

# The echo is a fresh interpreter (spawn model: this process holds a router session).
ECHO = """
import sys
import zenoh
from riskfield.services.runtime.processes import client_session
with client_session(sys.argv[1]) as s:
    # BLOCK: a DROP publisher may shed a megabyte pong under load, and the round trip would never end
    pub = s.declare_publisher("bench/pong", congestion_control=zenoh.CongestionControl.BLOCK)
    sub = s.declare_subscriber("bench/ping", lambda smp: pub.put(smp.payload))
    print("ready", flush=True)
    sys.stdin.read()
"""


def _frame(h: int, w: int) -> PerceptionFrame:
    rng = np.random.default_rng(0)
    return PerceptionFrame(T_WC=np.eye(4), points=rng.random((h, w, 3), dtype=np.float32),
                           confidence=rng.random((h, w), dtype=np.float32),
                           labels=rng.integers(0, 150, (h, w)).astype(np.uint16), keyframe_id=1)


def _grid(n: int) -> EsdfGrid:
    return EsdfGrid(origin=(0, 0, 0), voxel_size=0.05, distance=np.ones((n, n, n), np.float32),
                    risk_group=np.zeros((n, n, n), np.uint8), groups=["high", "mid", "low"], max_distance=2.0,
                    unknown_is_occupied=False)


def _times(fn, repeat: int) -> np.ndarray:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return np.array(out) * 1e3


def _round_trips(payload: bytes, repeat: int) -> np.ndarray:
    import queue

    import zenoh

    from riskfield.services.runtime.processes import EmbeddedRouter, client_session

    def ping(i: int) -> bytes:  # numbered, so a late pong is never taken for the one awaited
        return i.to_bytes(8, "little") + payload[8:]

    with EmbeddedRouter() as router:
        echo = subprocess.Popen([sys.executable, "-c", ECHO, router.endpoint], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, text=True)
        try:
            assert echo.stdout is not None and echo.stdout.readline().strip() == "ready"
            with client_session(router.endpoint) as s:
                pongs: queue.Queue[int] = queue.Queue()
                sub = s.declare_subscriber(
                    "bench/pong", lambda smp: pongs.put(int.from_bytes(smp.payload.to_bytes()[:8], "little")))
                pub = s.declare_publisher("bench/ping", congestion_control=zenoh.CongestionControl.BLOCK)

                def answered(i: int, timeout_s: float) -> bool:
                    try:
                        while pongs.get(timeout=timeout_s) != i:
                            pass
                    except queue.Empty:
                        return False
                    return True

                # "ready" means the echo declared its subscriber, not that the router routes to it yet:
                # ping until the first pong, so no timed ping goes to a route not yet there.
                if not any(pub.put(ping(i)) or answered(i, 0.1) for i in range(100)):
                    raise TimeoutError("the echo never answered")
                out = []
                for i in range(100, 100 + repeat + 5):
                    t0 = time.perf_counter()
                    pub.put(ping(i))
                    if not answered(i, 5):
                        raise TimeoutError(f"no echo of ping {i} ({len(payload)} B) in 5 s")
                    out.append(time.perf_counter() - t0)
                sub.undeclare()
        finally:
            echo.communicate(timeout=10)
    return np.array(out[5:]) * 1e3


@app.command()
def codec(
    repeat: Annotated[int, typer.Option(help="Repetitions per row.")] = 50,
    out: Annotated[Path, typer.Option(help="Folder for summary.json.")] = Path("out/bench/codec"),
) -> None:
    """Encode/decode medians and p99 (ms), and the loopback round trip through a router."""
    rows: list[tuple[str, np.ndarray]] = []
    for name, msg in (("VelocityCommand", VelocityCommand.zero("bench")), ("PerceptionFrame 512x384", _frame(384, 512)),
                      ("EsdfGrid 101^3", _grid(101))):
        payload, kind = encode(msg), type(msg)
        rows.append((f"encode {name} ({len(payload) / 1e6:.2f} MB)", _times(lambda m=msg: encode(m), repeat)))
        rows.append((f"decode {name}", _times(lambda p=payload, t=kind: decode(p, t), repeat)))
    # the last: an encoded 512x384 pointmap, the camera path's sim/truth and perception/frame hops
    for size in (64, 1_000_000, len(encode(_frame(384, 512)))):
        rows.append((f"zenoh round trip, {size} B, 2 processes", _round_trips(b"x" * size, repeat)))
    table = Table("operation", "median ms", "p99 ms", title="riskfield bench codec")
    summary = {}
    for name, t in rows:
        summary[name] = st = timing_stats(t)
        table.add_row(name, f"{st['median']:.3f}", f"{st['p99']:.3f}")
    Console().print(table)
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
