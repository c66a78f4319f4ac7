"""``riskfield bench link``: the bytes per second each key puts on the robot ↔ server link, at the
defaults, and the link budget for one robot (robot → server ≤ 0.5 MB/s, server → robot ≤ 1 MB/s).

The sim stack (simulator on the navigation scenario, perception ``sim``, mapping, safety filter,
navigator, the scripted operator driving the four corners) runs on one router; a subscriber to every
key under the robot's prefix counts samples and payload bytes for ``--duration`` seconds once the
first map is out. Each key is then placed on the split of ``riskfield.experiments.link`` (robot:
camera/simulator, filter, bridges; server: perception, mapping, navigator, operator): what crosses
the link is the keys whose consumers are on the other site, at the rate the routers' downsampling
lets through. ``sim/truth`` (simulation only) is reported apart and never crosses a real link.

Each ``--encodings`` entry is one run of the stack with the simulator's ``image_encoding`` set to it
(default: ``jpeg``, today's default, then ``rgb8``, the raw images: before / after from one command).
Writes ``summary.json`` and ``table.md`` to ``--out``; exits 1 when the first encoding's run is over
budget.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from riskfield.experiments.link import BUDGET, DOWN, SIM_ONLY, UP, KeyTraffic, direction, totals, traffic, within_budget

app = typer.Typer(add_completion=False)

#: The compose `sim` profile's operator route, once round (docker-compose.yml: ten rounds).
CORNERS = [["a", 2.0, -2.0], ["b", 2.0, 2.0], ["c", -2.0, 2.0], ["d", -2.0, -2.0]]


def measure(encoding: str, duration_s: float, robot: str, say: Console) -> tuple[list[KeyTraffic], float]:
    """One run of the sim stack; the traffic per key and the window's length."""
    from riskfield.experiments.stack import Stack
    from riskfield.services.runtime.processes import wait_until

    counts: dict[str, list[int]] = {}
    lock = threading.Lock()
    counting = threading.Event()
    head = f"rf/{robot}/"

    def on_sample(sample: Any) -> None:
        if not counting.is_set():
            return
        key = str(sample.key_expr)
        rel = key[len(head):] if key.startswith(head) else key
        n = len(sample.payload)
        with lock:
            c = counts.setdefault(rel, [0, 0])
            c[0] += 1
            c[1] += n

    with Stack(robot=robot) as stack:
        sub = stack.session.declare_subscriber(f"rf/{robot}/**", on_sample)
        got_map = threading.Event()
        esdf = stack.session.declare_subscriber(stack.keys.esdf, lambda _s: got_map.set())
        say.print(f"[dim]{encoding}: starting the sim stack[/dim]")
        for label, args in (("simulator", ["--set", f"image_encoding={encoding}"]),
                            ("perception", ["--set", "geometry=sim", "--set", "labels=sim"]),
                            ("mapping", []), ("safety-filter", []), ("navigator", []),
                            ("operator", ["--set", f"targets={json.dumps(CORNERS)}"])):
            stack.start(label, label, args, timeout_s=180.0)
        if not wait_until(got_map.is_set, 120.0):
            raise RuntimeError("no map/esdf within 120 s")
        counting.set()
        t0 = time.monotonic()
        time.sleep(duration_s)  # the measurement window itself, not a synchronisation
        counting.clear()
        window = time.monotonic() - t0
        sub.undeclare()
        esdf.undeclare()
    with lock:
        return traffic({k: (v[0], v[1]) for k, v in counts.items()}, window), window


def table(rows: list[KeyTraffic]) -> list[str]:
    lines = ["| key | crosses | rate (Hz) | message | on the stack (MB/s) | on the link (MB/s) |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        d = direction(r.key)
        link = f"{r.link_bytes_per_s / 1e6:.3f}" if d in (UP, DOWN) else "—"
        size = f"{r.mean_bytes / 1e3:.1f} KB" if r.mean_bytes >= 1e3 else f"{r.mean_bytes:.0f} B"
        lines.append(f"| `{r.key}` | {d} | {r.rate_hz:.1f} | {size} | {r.bytes_per_s / 1e6:.3f} | {link} |")
    tot = totals(rows)
    ok = within_budget(tot)
    for d in (UP, DOWN):
        lines.append(f"| **{d}** | | | | | **{tot[d] / 1e6:.3f}** (budget {BUDGET[d] / 1e6:g}: "
                     f"{'within' if ok[d] else 'OVER'}) |")
    lines.append(f"| {SIM_ONLY} (never on a real link) | | | | {tot[SIM_ONLY] / 1e6:.3f} | |")
    return lines


@app.command()
def main(
    duration: Annotated[float, typer.Option(min=1.0, help="Measurement window of each run (s).")] = 20.0,
    encodings: Annotated[str, typer.Option(help="Comma-separated image encodings, one run each (jpeg, rgb8).")
                         ] = "jpeg,rgb8",
    robot: Annotated[str, typer.Option(help="Robot id of the stack.")] = "link1",
    out: Annotated[Path, typer.Option(help="Folder for summary.json and table.md.")] = Path("out/bench/link"),
) -> None:
    """Bytes per second per key across the robot ↔ server link, and the budget check."""
    say = Console(stderr=True, highlight=False)
    names = [e.strip() for e in encodings.split(",") if e.strip()]
    bad = [e for e in names if e not in ("jpeg", "rgb8")]
    if not names or bad:
        raise typer.BadParameter(f"encodings {bad or names!r}: use jpeg and/or rgb8")
    out.mkdir(parents=True, exist_ok=True)
    from riskfield.services.runtime.warmup import warm_up

    warm_up(["simulator", "perception", "mapping", "safety-filter"], say=lambda line: say.print(f"[dim]{line}[/dim]"))
    summary: dict[str, dict] = {}
    md: list[str] = []
    for enc in names:
        rows, window = measure(enc, duration, robot, say)
        tot = totals(rows)
        summary[enc] = {
            "window_s": window,
            "keys": {r.key: {"direction": direction(r.key), "rate_hz": r.rate_hz, "mean_bytes": r.mean_bytes,
                             "bytes_per_s": r.bytes_per_s, "link_bytes_per_s": r.link_bytes_per_s} for r in rows},
            "totals_bytes_per_s": tot,
            "within_budget": within_budget(tot),
        }
        md += [f"### camera/image as {enc} ({window:.1f} s window)", "", *table(rows), ""]
    (out / "summary.json").write_text(json.dumps({"budget_bytes_per_s": BUDGET, "runs": summary}, indent=2))
    (out / "table.md").write_text("\n".join(md))
    print("\n".join(md))
    if not all(summary[names[0]]["within_budget"].values()):
        raise typer.Exit(1)
