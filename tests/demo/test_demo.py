"""The main job end to end: `riskfield demo` runs the whole stack as processes and reports."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from riskfield.demo import report as rp
from riskfield.demo.scenario import LOOP, navigation_waypoints


def test_report_helpers_on_hand_made_series():
    assert rp.episodes(np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)) == 3
    assert rp.episodes(np.zeros(4, bool)) == 0
    lat = rp.command_latency_ms([0.0, 1.0, 2.0], [0.001, 1.004, 1.5])
    np.testing.assert_allclose(lat, [1.0, 4.0])  # the last reference got no answer: not counted
    t = np.array([0.0, 1.0, 2.0, 3.0])
    assert rp.first_intervention(t, np.array([1, 0, 1, 1], bool), (0.5, 3.0)) == 2.0
    assert rp.first_intervention(t, np.zeros(4, bool), (0.0, 3.0)) is None
    assert navigation_waypoints(1.5) == [*LOOP, *LOOP[:2]]


@pytest.mark.slow
def test_demo_shows_the_dog_makes_the_filter_intervene_earlier_than_the_ball(tmp_path):
    """The demo's claim (the paper's teleop experiment): with the high-risk dog the filter
    intervenes farther away and keeps a larger clearance than with the low-risk ball; nothing
    is hit, and both experiments (teleoperation, then navigation) complete."""
    out = tmp_path / "demo"
    try:
        r = subprocess.run([sys.executable, "-m", "riskfield", "demo", "--out", str(out), "--budget", "80"],
                           capture_output=True, text=True, timeout=420)
        summary_path = out / "summary.json"
        assert summary_path.is_file(), r.stdout + r.stderr[-3000:]
        s = json.loads(summary_path.read_text())
        log = (out / "stack.log").read_text()[-4000:] if (out / "stack.log").is_file() else r.stderr[-3000:]
        assert s["services_ended_badly"] == [], log
        assert s["experiments_completed"] is True and s["navigation"]["completed"] is True, s["phases_s"]
        assert s["collisions"] == 0 and s["min_clearance_m"] > 0, s["min_clearance_per_object_m"]
        ball, dog = s["teleop"]["ball (low risk)"], s["teleop"]["dog (high risk)"]
        assert dog["first_intervention_m"] is not None, s["teleop"]
        # A filter that never intervened near the ball let the robot come as close as it liked:
        # an intervention at distance 0 at the latest.
        ball_first = ball["first_intervention_m"] if ball["first_intervention_m"] is not None else 0.0
        assert dog["first_intervention_m"] > ball_first, s["teleop"]
        assert dog["min_clearance_m"] > ball["min_clearance_m"], s["teleop"]
        assert r.returncode == 0, r.stdout[-3000:]
        for f in ("teleop.png", "navigation.png", "scenario.yaml"):
            assert (out / f).is_file(), f
    finally:
        # The recording is gigabytes: never leave it behind, pass or fail.
        (out / "recording.mcap").unlink(missing_ok=True)
