"""``riskfield bench link``: the bytes per second each key puts on the robot ↔ server link, at the
defaults, and the link budget for one robot (robot → server ≤ 0.5 MB/s, server → robot ≤ 1 MB/s).

The sim stack (simulator on the navigation scenario, perception ``sim``, mapping, safety filter,
navigator, the scripted operator driving the four corners) runs on one router; a subscriber to every
key under the robot's prefix counts samples and payload bytes for ``--duration`` seconds once the
first map is out. Each key is then placed on the split of ``riskfield.experiments.link`` (robot:
camera/simulator, filter, bridges; server: perception, mapping, navigator, operator): what crosses
the link is the keys whose consumers are on the other site, at the rate the routers' downsampling
lets through. ``sim/truth`` (simulation only) is reported apart and never crosses a real link.

What the routers' link itself carries server → robot is measured too: a robot site's router dials the
stack's through a loopback relay that counts the bytes (``shaped_link``) and subscribes to the server →
robot keys, as a robot's filter does; two such sites run side by side, one with the routers' default
LZ4 compression (``RouterSettings.compression``), one without.

Each ``--encodings`` entry is one run of the stack with the simulator's ``image_encoding`` set to it
(default: ``jpeg``, the simulator's default, then ``rgb8``, the raw images: before / after from one command).
Writes ``summary.json`` and ``table.md`` to ``--out``; exits 1 when the first encoding's run is over
budget.
"""

from __future__ import annotations

import contextlib
import json
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated, Any

import typer
import zenoh
from rich.console import Console

from riskfield.experiments.link import (
    BUDGET,
    DIRECTION,
    DOWN,
    SIM_ONLY,
    UP,
    KeyTraffic,
    direction,
    totals,
    traffic,
    within_budget,
)
from riskfield.experiments.shaped_link import ShapedLink

app = typer.Typer(add_completion=False)

#: The compose `sim` profile's operator route, once round (docker-compose.yml: ten rounds).
CORNERS = [["a", 2.0, -2.0], ["b", 2.0, 2.0], ["c", -2.0, 2.0], ["d", -2.0, -2.0]]


#: The stack's services, as the bench starts them: (label, arguments beyond the image encoding's).
SERVICES = (("simulator", []), ("perception", ["--set", "geometry=sim", "--set", "labels=sim"]), ("mapping", []),
            ("safety-filter", []), ("navigator", []), ("operator", ["--set", f"targets={json.dumps(CORNERS)}"]))


def down_keys(root: str) -> list[str]:
    """Key expressions of what goes server → robot (``experiments.link``): what a robot site subscribes to."""
    rels = [rel for rel, d in DIRECTION.items() if d == DOWN]
    rels += [f"status/{label}" for label, _ in SERVICES if direction(f"status/{label}") == DOWN]
    return [f"{root}/{rel}/**" for rel in rels]  # ``**`` matches no chunk too: the key itself


@contextlib.contextmanager
def robot_site(router_port: int, root: str, compression: bool,
               on_sample: Callable[[zenoh.Sample], None] = lambda _s: None) -> Iterator[ShapedLink]:
    """A robot site's router dialling the router on ``router_port`` through a loopback relay that
    counts the bytes (``shaped_link``, unshaped), and a session on it subscribed to the server →
    robot keys (``on_sample``), so Zenoh routes them across that link as it would to a robot: its
    bytes are what the link carries."""
    from riskfield.services.runtime.processes import client_session, free_port, router_settings
    from riskfield.services.runtime.session import zenoh_config

    with ShapedLink(router_port) as link:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        settings = router_settings(endpoint, [link.endpoint]).model_copy(update={"compression": compression})
        router = zenoh.open(zenoh_config(settings))
        try:
            with client_session(endpoint) as session:
                subs = [session.declare_subscriber(k, on_sample) for k in down_keys(root)]
                yield link
                for sub in subs:
                    sub.undeclare()
        finally:
            router.close()


def measure(encoding: str, duration_s: float, robot: str, say: Console
            ) -> tuple[list[KeyTraffic], float, dict[str, float]]:
    """One run of the sim stack; the traffic per key, the window's length, and the bytes/s the
    routers' link carried server → robot with and without compression (``lz4``, ``none``)."""
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

    with Stack(robot=robot) as stack, contextlib.ExitStack() as sites:
        links = {name: sites.enter_context(robot_site(stack.router.port, stack.keys.root, name == "lz4"))
                 for name in ("lz4", "none")}
        sub = stack.session.declare_subscriber(f"rf/{robot}/**", on_sample)
        got_map = threading.Event()
        esdf = stack.session.declare_subscriber(stack.keys.esdf, lambda _s: got_map.set())
        say.print(f"[dim]{encoding}: starting the sim stack[/dim]")
        for label, args in SERVICES:
            extra = ["--set", f"image_encoding={encoding}"] if label == "simulator" else []
            stack.start(label, label, [*args, *extra], timeout_s=180.0)
        if not wait_until(got_map.is_set, 120.0):
            raise RuntimeError("no map/esdf within 120 s")
        wire0 = {name: link.down.bytes for name, link in links.items()}
        counting.set()
        t0 = time.monotonic()
        time.sleep(duration_s)  # the measurement window itself, not a synchronisation
        counting.clear()
        window = time.monotonic() - t0
        wire = {name: (link.down.bytes - wire0[name]) / window for name, link in links.items()}
        sub.undeclare()
        esdf.undeclare()
    with lock:
        return traffic({k: (v[0], v[1]) for k, v in counts.items()}, window), window, wire


def table(rows: list[KeyTraffic], wire: dict[str, float]) -> list[str]:
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
    lines.append(f"| **{DOWN}, bytes on the routers' link**: LZ4 (the routers' default) / without | | | | | "
                 f"**{wire['lz4'] / 1e6:.3f}** / {wire['none'] / 1e6:.3f} |")
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
        rows, window, wire = measure(enc, duration, robot, say)
        tot = totals(rows)
        summary[enc] = {
            "window_s": window,
            "keys": {r.key: {"direction": direction(r.key), "rate_hz": r.rate_hz, "mean_bytes": r.mean_bytes,
                             "bytes_per_s": r.bytes_per_s, "link_bytes_per_s": r.link_bytes_per_s} for r in rows},
            "totals_bytes_per_s": tot,
            "down_wire_bytes_per_s": wire,
            "within_budget": within_budget(tot),
        }
        md += [f"### camera/image as {enc} ({window:.1f} s window)", "", *table(rows, wire), ""]
    (out / "summary.json").write_text(json.dumps({"budget_bytes_per_s": BUDGET, "runs": summary}, indent=2))
    (out / "table.md").write_text("\n".join(md))
    print("\n".join(md))
    if not all(summary[names[0]]["within_budget"].values()):
        raise typer.Exit(1)
