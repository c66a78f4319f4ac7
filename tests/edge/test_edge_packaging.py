"""Edge code stays light (robot extra only) and the latency bench runs end to end."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("open3d", "torch", "numba", "edt", "matplotlib")


def test_edge_nodes_import_nothing_heavy() -> None:
    code = (
        "import sys\n"
        "import riskfield.edge.limo.node, riskfield.edge.limo.emulator, riskfield.edge.joystick.node\n"
        "import riskfield.edge.joystick.keyboard, riskfield.edge.mavlink.node, riskfield.edge.mavlink.fake_vehicle\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
        "print('evdev' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    heavy, evdev = out.stdout.split("\n")[:2]
    assert heavy == "[]"
    assert evdev == "False"  # imported only when a real device is opened


@pytest.mark.slow  # the bench itself: router, relay and probe processes
def test_latency_bench_runs_with_the_relay(tmp_path: Path) -> None:
    """Only that it measures every event and writes its summary; the numbers are for the bench."""
    res = subprocess.run(
        [sys.executable, "-m", "riskfield", "bench", "latency", "--filter", "relay", "--samples", "10", "--warmup",
         "2", "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["lost"] == 0 and summary["total"]["n"] == 10
