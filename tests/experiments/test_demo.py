"""The main job end to end: `riskfield demo` runs the whole stack as processes and reports."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from riskfield.experiments.latency import command_latency_ms
from riskfield.experiments.scenarios import LOOP, collisions, episodes, navigation_waypoints
from riskfield.experiments.teleop import first_intervention


def test_report_helpers_on_hand_made_series():
    assert episodes(np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)) == 3
    assert episodes(np.zeros(4, bool)) == 0
    assert collisions(np.array([0.3, -0.01, -0.02, 0.1, -0.5])) == 2
    lat = command_latency_ms([0.0, 1.0, 2.0], [0.001, 1.004, 1.5])
    np.testing.assert_allclose(lat, [1.0, 4.0])  # the last reference got no answer: not counted
    # sent before the filter was up: waiting for its start is not its latency
    np.testing.assert_allclose(command_latency_ms([0.0, 1.0], [0.9, 1.004]), [900.0, 4.0])
    np.testing.assert_allclose(command_latency_ms([0.0, 1.0], [0.9, 1.004], since=0.5), [4.0])
    t = np.array([0.0, 1.0, 2.0, 3.0])
    assert first_intervention(t, np.array([1, 0, 1, 1], bool), (0.5, 3.0)) == 2.0
    assert first_intervention(t, np.zeros(4, bool), (0.0, 3.0)) is None
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
        _assert_viewable_recording(out / "recording.mcap")
    finally:
        # The recording is gigabytes: never leave it behind, pass or fail.
        (out / "recording.mcap").unlink(missing_ok=True)


def _assert_viewable_recording(path) -> None:
    """The demo's recording opens in Foxglove (its well-known schemas, decodable with the schema in
    the file) and stays small enough to share."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    assert path.stat().st_size <= 150 * 1024 * 1024, path.stat().st_size
    decode_with = DecoderFactory()
    decoded: dict[str, object] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding == "protobuf" and schema.name not in decoded:
                decoded[schema.name] = decode_with.decoder_for("protobuf", schema)(message.data)
    for name in ("foxglove.CompressedImage", "foxglove.Grid", "foxglove.PointCloud", "foxglove.FrameTransform"):
        assert name in decoded, sorted(decoded)
    assert decoded["foxglove.CompressedImage"].format == "jpeg"
    assert len(decoded["foxglove.Grid"].data) > 0 and len(decoded["foxglove.PointCloud"].data) > 0
