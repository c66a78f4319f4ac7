"""The main job end to end: `riskfield demo` runs the whole stack as processes and reports."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from riskfield.experiments.demo.report import command_latency_ms
from riskfield.experiments.scenarios import LOOP, collisions, episodes, navigation_waypoints
from riskfield.experiments.teleop import first_intervention


def test_report_helpers_on_hand_made_series():
    assert episodes(np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)) == 3
    assert episodes(np.zeros(4, bool)) == 0
    assert collisions(np.array([0.3, -0.01, -0.02, 0.1, -0.5])) == 2
    lat = command_latency_ms([0.0, 1.0, 2.0], [0.001, 1.004, 1.5])
    np.testing.assert_allclose(lat, [1.0, 4.0])  # the last reference got no answer: not counted
    t = np.array([0.0, 1.0, 2.0, 3.0])
    assert first_intervention(t, np.array([1, 0, 1, 1], bool), (0.5, 3.0)) == 2.0
    assert first_intervention(t, np.zeros(4, bool), (0.0, 3.0)) is None
    assert navigation_waypoints(1.5) == [*LOOP, *LOOP[:2]]


@pytest.mark.slow
def test_demo_runs_the_stack_and_writes_a_report(tmp_path):
    r = subprocess.run([sys.executable, "-m", "riskfield", "demo", "--out", str(tmp_path), "--budget", "80"],
                       capture_output=True, text=True, timeout=420)
    summary_path = tmp_path / "summary.json"
    assert summary_path.is_file(), r.stdout + r.stderr[-3000:]
    s = json.loads(summary_path.read_text())
    assert s["services_ended_badly"] == [], (tmp_path / "stack.log").read_text()[-4000:]
    assert s["collisions"] == 0 and s["min_clearance_m"] > 0
    for name in ("ball (low risk)", "dog (high risk)"):
        assert s["teleop"][name]["min_clearance_m"] is not None
    assert s["rates_hz"]["state"] > 5 and s["rates_hz"]["map/esdf"] > 0.5 and s["rates_hz"]["cmd/safe"] > 10
    assert s["filter_step_us"]["median"] > 0
    for f in ("recording.mcap", "teleop.png", "navigation.png", "stack.log", "scenario.yaml"):
        assert (tmp_path / f).is_file(), f
    assert "Teleoperation" in r.stdout
