"""The replay path of ``riskfield bench latency`` (``experiments/replay.py``): the recording's
compact frames and their error against the full ones, and how a frame is matched to the filter's step."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from riskfield.experiments.replay import core_costs, record, replay, timings

MS = 1_000_000


def test_each_frame_meets_the_first_step_on_a_map_that_contains_it():
    sent = [(100 * MS, 0.3, 100 * MS), (200 * MS, 0.4, 200 * MS), (300 * MS, 0.2, 300 * MS)]
    esdf = [(112 * MS, 100 * MS), (215 * MS, 200 * MS)]  # the third frame's never came
    # (arrival here, step stamp, stamp of the map it ran on): a step on the older map first, then on
    # the frame's own; the second frame's map is only stepped on after a newer one (its stamp ≥)
    steps = [(111 * MS, 110 * MS, 50 * MS), (114 * MS, 113 * MS, 100 * MS), (218 * MS, 217 * MS, 200 * MS - 400_000)]
    out = timings(sent, esdf, steps, {"mapping": {"integrate_ms": [3.0, 4.0]}})
    assert out["frames"] == 3 and out["lost"] == 1
    tot = out["frame_to_cmd_safe_ms"]
    assert tot["n"] == 2 and tot["max"] == pytest.approx(17.0) and tot["median"] == pytest.approx(15.0)
    st = out["stages_ms"]
    assert st["published → ESDF arrives here"]["max"] == pytest.approx(15.0)
    assert st["ESDF arrives here → the filter's step on it"]["median"] == pytest.approx(1.5)
    assert out["node_ms"]["mapping integrate"]["n"] == 2 and out["node_ms"]["mapping ESDF update"] is None


def test_the_recording_is_compact_and_close_to_the_full_size_frames():
    rec = record(4)
    s = rec.summary()
    assert len(rec.frames) == len(rec.states) == 4
    f = rec.frames[-1]
    assert f.points is None and f.depth.dtype == np.float16 and f.pixels == (192, 256) and f.intrinsics is not None
    assert s["full_frame_bytes_median"] > 3.5e6 and s["compact_frame_bytes_median"] < 0.4e6
    assert s["truth_bytes_strided"] < s["truth_bytes_full"] / 7
    # at 1–4 m: float16 (≤ 1 mm) and the fused points' sub-pixel offsets from their ray
    assert s["error_pixels"] > 10_000 and s["error_m_median"] < 1e-3 and s["error_m_max"] < 0.03
    # the maps built from the full frames and from their compact form: a point error under a voxel moves
    # a surface by at most one voxel along each axis, so a distance by one diagonal step (√2 × 5 cm; a
    # wall near a voxel boundary 2.5–3 m away does, over a few % of the cells)
    m = s["map_agreement"]["full_compacted"]
    step = float(np.float32(0.05)) * np.sqrt(2)
    assert m["comparable"] and m["abs_diff_m_p99"] <= step + 1e-6 and m["obstacle_iou"] > 0.9


def test_the_mapping_cores_cost_per_frame_as_cpu_and_wall_time():
    out = core_costs(record(8, compare=False))
    for kind in ("cpu_ms", "wall_ms"):
        assert set(out[kind]) == {"decode", "integrate", "ESDF update", "total"}
        assert out[kind]["total"]["n"] == 7  # the first frame (of an empty volume) left out
    assert out["cpu_ms"]["integrate"]["median"] > 0 and out["wall_ms"]["total"]["max"] > 0


@pytest.mark.slow
def test_the_replay_times_every_frame_to_a_filter_step():
    from riskfield.experiments.demo.config import DemoConfig
    from riskfield.experiments.demo.run import camera_pipeline

    rec = record(30, compare=False)
    services = [s for s in camera_pipeline(DemoConfig()) if s[1] in ("mapping", "safety-filter")]
    out = replay(rec, services, warmup=10)
    assert out["frames"] == 20 and out["lost"] == 0
    assert out["frame_to_cmd_safe_ms"]["p99"] < 500  # generous: a loaded 2-core machine; the bench has the target


def test_the_bench_command_knows_the_replay_path():
    from riskfield.cli import app

    res = CliRunner().invoke(app, ["bench", "latency", "--help"])
    assert res.exit_code == 0 and "replay" in res.output
