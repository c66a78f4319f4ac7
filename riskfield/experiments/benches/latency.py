"""``riskfield bench latency``: joystick event → ``cmd/ref`` → safety filter → ``cmd/safe`` →
motion-frame bytes on the LIMO serial line, every node in its own process over a real router.

The bench process holds the Zenoh router, the LIMO chassis emulator (a pty) and a FIFO that
stands in for ``/dev/input/eventN``: it writes ``struct input_event`` records into the FIFO
(``t_send``) and the emulator thread notes when a motion frame carrying that command arrives
on the serial line (``t_serial``); both use ``time.perf_counter`` of this process. Each event
moves the stick to a new position, so each command value identifies its event; the value
alternates forward/backward, which keeps the emulated robot near its start. The filter gets a
synthetic ESDF with obstacles 15 m away (it passes the reference through unchanged) and the
LIMO node's odometry as its state. The bench also listens on ``cmd/ref`` and ``cmd/safe`` to
split the total into hops (those subscribers add a little load of their own).

``--filter relay`` replaces the safety filter by the relay node (cmd/ref → cmd/safe unchanged):
the transport-only baseline, and a way to run the bench before a filter exists.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from riskfield.edge.joystick.mapping import CODES, EV_ABS, EV_KEY, EV_SYN, SYN_REPORT, AxisSpec
from riskfield.edge.joystick.source import pack_event
from riskfield.edge.limo.emulator import ChassisEmulator
from riskfield.edge.limo.protocol import MotionCommand
from riskfield.experiments.stack import publish
from riskfield.protocol import EsdfGrid, Keys, VelocityCommand, decode, encode
from riskfield.services.runtime.processes import EmbeddedRouter, ProcessRunner, client_session, wait_until

app = typer.Typer(add_completion=False)
TARGET_P99_MS = 5.0
MAX_LINEAR = 0.5


def far_obstacles_esdf() -> EsdfGrid:
    """40 m × 40 m 2-D slice, 0.2 m voxels, a ring of low-risk obstacles 15 m from the origin."""
    n, voxel = 200, 0.2
    c = (np.arange(n) - n / 2) * voxel
    r = np.hypot(c[:, None], c[None, :])
    dist = np.clip(15.0 - r, -5.0, 5.0).astype(np.float32)[:, :, None]
    return EsdfGrid(origin=(-20.0, -20.0, 0.0), voxel_size=voxel, distance=dist,
                    risk_group=np.full(dist.shape, 3, np.uint8), groups=["high", "mid", "low"],
                    max_distance=5.0, unknown_is_occupied=False)


def stick_values(n: int) -> list[tuple[int, int]]:
    """(raw ABS_Y, command in mm/s) per event: alternating forward/back, consecutive values distinct."""
    axis = AxisSpec.parse("-ABS_Y")
    assert axis is not None
    out = []
    for i in range(n):
        raw = 100 + 4 * (i // 2 % 25) if i % 2 == 0 else 923 - 4 * (i // 2 % 25)
        out.append((raw, round(MAX_LINEAR * axis.normalise(raw) * 1000)))
    return out


class Timeline:
    """Arrival times of command values at one observation point (thread-safe append)."""

    def __init__(self) -> None:
        self.items: list[tuple[float, int]] = []
        self.lock = threading.Lock()

    def add(self, t: float, mm: int) -> None:
        with self.lock:
            self.items.append((t, mm))

    def first(self, mm: int, after: float, within: float) -> float | None:
        with self.lock:
            for t, v in self.items:
                if v == mm and after <= t <= after + within:
                    return t
        return None


def percentiles(x: list[float]) -> dict[str, float]:
    if not x:
        return {"n": 0}
    a = np.asarray(x)
    return {"n": len(x), "p50_ms": float(np.percentile(a, 50)), "p90_ms": float(np.percentile(a, 90)),
            "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max()), "mean_ms": float(a.mean())}


@app.command()
def latency(
    samples: Annotated[int, typer.Option(help="Measured events.")] = 300,
    warmup: Annotated[int, typer.Option(help="Events sent first and not counted.")] = 20,
    rate_hz: Annotated[float, typer.Option(help="Events per second.")] = 20.0,
    filter_service: Annotated[str, typer.Option("--filter", help="safety-filter, or relay (no filter).")] =
    "safety-filter",
    poll_ms: Annotated[float, typer.Option(help="Joystick poll period (ms); events wake it at once anyway.")] = 10.0,
    out: Annotated[Path, typer.Option(help="Folder for summary.json.")] = Path("out/bench/latency"),
    filter_set: Annotated[list[str] | None, typer.Option("--filter-set", help="key=value for the filter.")] = None,
    hops: Annotated[bool, typer.Option(help="Also time cmd/ref and cmd/safe (adds two subscribers here).")] = True,
) -> None:
    """Measure end-to-end teleop latency; p99 target ≤ 5 ms on loopback."""
    console = Console()
    robot = f"bench_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    values = stick_values(warmup + samples)
    serial = Timeline()
    ref, safe = Timeline(), Timeline()

    def on_frame(t: float, msg: object) -> None:
        if isinstance(msg, MotionCommand):
            serial.add(t, round(msg.linear * 1000))

    tmp = Path(tempfile.mkdtemp(prefix="rf-latency-"))
    fifo = tmp / "event-joystick"
    os.mkfifo(fifo)
    esdf = far_obstacles_esdf()
    common = ["--robot", robot]
    if filter_service == "relay":
        filter_args = ["--set", "in_key=cmd/ref", "--set", "out_key=cmd/safe", "--set", "queue=latest"]
    else:
        filter_args = [a for kv in (filter_set or []) for a in ("--set", kv)]
    console.print(f"[bold]latency bench[/bold]: joystick → {filter_service} → limo, robot id {robot}")
    with EmbeddedRouter() as router, ChassisEmulator(on_frame=on_frame) as emu, \
            client_session(router.endpoint) as session, ProcessRunner(router.endpoint, keys) as runner:
        subs = []
        for key, tl in ((keys.cmd_ref, ref), (keys.cmd_safe, safe)) if hops else ():
            def cb(sample: object, tl: Timeline = tl) -> None:
                t = time.perf_counter()
                msg = decode(sample.payload.to_bytes(), VelocityCommand)  # type: ignore[attr-defined]
                tl.add(t, round(msg.linear[0] * 1000))
            subs.append(session.declare_subscriber(key, cb))
        runner.add("limo", "limo", [*common, "--set", f"port={emu.path}", "--set", "motion_mode=differential"])
        runner.add(filter_service, filter_service, [*common, *filter_args])
        runner.add("joystick", "joystick", [*common, "--set", "source=raw", "--set", f"device={fifo}",
                                            "--set", "speed_scale=", "--set", f"max_linear={MAX_LINEAR}",
                                            "--set", f"poll_s={poll_ms / 1000}"])
        stop_esdf = threading.Event()

        def esdf_loop() -> None:
            payload = encode(esdf)
            while not stop_esdf.is_set():
                publish(session, keys.esdf, payload)
                stop_esdf.wait(0.1)

        esdf_thread = threading.Thread(target=esdf_loop, daemon=True)
        esdf_thread.start()
        fd = -1
        try:
            runner.start()
            for label, child in runner.children.items():
                if not runner.wait_ready(session, [label], 30.0):
                    raise RuntimeError(f"{label} did not come up:\n{child.output}")
            if not wait_until(lambda: emu.model.control_mode == 1, 10.0):
                raise RuntimeError("the LIMO node did not enable command mode")
            fd = os.open(fifo, os.O_WRONLY)
            os.write(fd, pack_event(EV_KEY, CODES["BTN_TRIGGER"], 1) + pack_event(EV_SYN, SYN_REPORT, 0))
            time.sleep(0.5)
            sends = []
            period = 1.0 / rate_hz
            next_t = time.perf_counter()
            for raw, mm in values:
                next_t += period
                data = pack_event(EV_ABS, CODES["ABS_Y"], raw) + pack_event(EV_SYN, SYN_REPORT, 0)
                t = time.perf_counter()
                os.write(fd, data)
                sends.append((t, mm))
                time.sleep(max(0.0, next_t - time.perf_counter()))
            time.sleep(0.5)
        finally:
            if fd >= 0:
                os.write(fd, pack_event(EV_KEY, CODES["BTN_TRIGGER"], 0) + pack_event(EV_SYN, SYN_REPORT, 0))
                os.close(fd)
            stop_esdf.set()
            esdf_thread.join(2.0)
            runner.stop()
            outputs = {label: child.output[-2000:] for label, child in runner.children.items()}
            for s in subs:
                s.undeclare()
    total, hop_ref, hop_filter, hop_limo = [], [], [], []
    lost = 0
    for t_send, mm in sends[warmup:]:
        t_serial = serial.first(mm, t_send, 1.0)
        if t_serial is None:
            lost += 1
            continue
        total.append((t_serial - t_send) * 1e3)
        t_ref, t_safe = ref.first(mm, t_send, 1.0), safe.first(mm, t_send, 1.0)
        if t_ref is not None and t_safe is not None and t_ref <= t_safe <= t_serial:
            hop_ref.append((t_ref - t_send) * 1e3)
            hop_filter.append((t_safe - t_ref) * 1e3)
            hop_limo.append((t_serial - t_safe) * 1e3)
    stats = {"total": percentiles(total), "event_to_cmd_ref": percentiles(hop_ref),
             "cmd_ref_to_cmd_safe": percentiles(hop_filter), "cmd_safe_to_serial": percentiles(hop_limo)}
    table = Table("path", "n", "p50 ms", "p90 ms", "p99 ms", "max ms", title=f"teleop latency ({filter_service})")
    for name, st in stats.items():
        if st["n"]:
            table.add_row(name, str(st["n"]), *(f"{st[k]:.2f}" for k in ("p50_ms", "p90_ms", "p99_ms", "max_ms")))
        else:
            table.add_row(name, "0", "-", "-", "-", "-")
    console.print(table)
    p99 = stats["total"].get("p99_ms")
    ok = p99 is not None and p99 <= TARGET_P99_MS and lost == 0
    console.print(f"lost events: {lost} of {samples};  target p99 ≤ {TARGET_P99_MS} ms: "
                  + ("[green]met[/green]" if ok else "[red]not met[/red]"))
    out.mkdir(parents=True, exist_ok=True)
    summary = {"bench": "latency", "filter": filter_service, "samples": samples, "warmup": warmup,
               "rate_hz": rate_hz, "poll_ms": poll_ms, "hops": hops, "lost": lost, "target_p99_ms": TARGET_P99_MS,
               "target_met": ok, **stats}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    console.print(f"wrote {out / 'summary.json'}")
    if lost == samples:
        console.print("[red]no event reached the serial line; node output tails:[/red]")
        for name, text in outputs.items():
            console.print(f"--- {name}\n{text}")
        raise typer.Exit(1)
