"""``riskfield bench startup``: how long each node of the demo takes to start, from process spawn to
its "up" log line (subscribed, kernels loaded, serving), its first start and its second.

Besides the wall time, the CPU time each start used (user + system, all its threads): on a busy
machine the wall time is mostly waiting for a core, the CPU time is what an idle one would need.

Each node starts alone (one at a time, on this process's embedded router), with the demo's own
arguments, as ``riskfield demo`` starts it; the kernels are warmed first (``riskfield warmup``: what
``make setup`` does), so the first start is the first after set-up. Numbers for docs/deployment.md.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
import yaml
from rich.console import Console
from rich.table import Table

app = typer.Typer(add_completion=False)

UP = re.compile(r" up as \S+ on .*, ([0-9.]+) s after spawn")


def demo_starts(out: Path) -> list[tuple[str, list[str]]]:
    """(service, arguments) of every node ``riskfield demo`` starts besides its router."""
    from riskfield.experiments.demo.run import DemoConfig, camera_pipeline
    from riskfield.experiments.scenarios import TELEOP_TARGETS, scenario
    from riskfield.experiments.teleop import operator_args

    cfg = DemoConfig(out=out)
    (out / "scenario.yaml").write_text(yaml.safe_dump(scenario(), sort_keys=False))
    starts = [("record", ["--set", f"out={out}"])]
    starts += [(service, args) for _, service, args in camera_pipeline(cfg)]
    starts += [("navigator", []), ("operator", operator_args(TELEOP_TARGETS, 0, 6.0))]
    return starts


def _cpu_s(pid: int) -> float:
    """CPU seconds (user + system, all threads) a process has used so far (``/proc/PID/stat`` fields
    14 and 15): what its start costs whatever else runs, the time it takes on an idle machine when it
    does not wait for anything."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


@app.command()
def main(
    repeat: Annotated[int, typer.Option(min=1, help="Starts of each node (the first is the first after set-up).")
                      ] = 2,
    out: Annotated[Path, typer.Option(help="Folder for summary.json.")] = Path("out/bench/startup"),
    timeout: Annotated[float, typer.Option(help="Longest start waited for (s).")] = 300.0,
) -> None:
    """Spawn → "up" of every node of the demo, started alone, ``repeat`` times each."""
    from riskfield.services.runtime.processes import Child, EmbeddedRouter, service_argv, wait_until
    from riskfield.services.runtime.warmup import warm_up

    console = Console(stderr=True, highlight=False)
    out.mkdir(parents=True, exist_ok=True)
    warm_up(say=lambda line: console.print(f"[dim]{line}[/dim]"))
    rows: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="rf-startup-") as tmp, EmbeddedRouter() as router:
        for service, args in demo_starts(Path(tmp)):
            spawn_to_up, own, cpu = [], [], []
            for i in range(repeat):
                argv = service_argv(service, ["--connect", router.endpoint, "--robot", f"startup{i}", *args])
                child = Child(service, service, argv)
                t0 = time.monotonic()
                child.start()
                try:
                    if not wait_until(lambda c=child: UP.search(c.output) is not None or not c.alive(), timeout):
                        raise typer.Exit(f"{service} did not come up in {timeout} s:\n{child.output[-2000:]}")
                    match = UP.search(child.output)
                    if match is None:
                        raise typer.Exit(f"{service} ended before it was up:\n{child.output[-2000:]}")
                    spawn_to_up.append(time.monotonic() - t0)
                    own.append(float(match.group(1)))
                    cpu.append(_cpu_s(child.proc.pid) if child.proc is not None else float("nan"))
                    compiled = "compiling kernel" in child.output
                finally:
                    child.stop()
            rows[service] = {"spawn_to_up_s": spawn_to_up, "node_says_s": own, "cpu_s": cpu,
                             "compiled_at_start": compiled}
            pairs = zip(spawn_to_up, cpu, strict=True)
            console.print(f"{service}: " + ", ".join(f"{t:.2f} s ({c:.2f} s CPU)" for t, c in pairs))
    table = Table("node", *(f"start {i + 1}: s (CPU s)" for i in range(repeat)), title="spawn → up")
    for service, r in rows.items():
        table.add_row(service, *(f"{t:.2f} ({c:.2f})" for t, c in zip(r["spawn_to_up_s"], r["cpu_s"], strict=True)))
    console.print(table)
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else []
    summary = {"nodes": rows, "loadavg": load,
               "max_first_start_s": float(np.max([r["spawn_to_up_s"][0] for r in rows.values()]))}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
