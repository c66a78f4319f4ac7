"""The camera → cmd/safe latency and ESDF content age, from stamps and receive times."""

from __future__ import annotations

import pytest

from riskfield.experiments.latency import (
    arrival_age_ms,
    camera_to_command_ms,
    content_age_from_image_ms,
    content_age_ms,
    first_arrivals,
    latency_summary,
    pipeline_stages,
)


def test_camera_to_command_takes_the_first_command_after_each_new_esdf() -> None:
    # ESDFs from frames stamped 0.00 and 0.10 arrive at 0.05 and 0.16 (the second one twice:
    # republished, same content); commands every 20 ms.
    esdf_t, esdf_stamp = [0.05, 0.16, 0.17], [0.00, 0.10, 0.10]
    safe_t = [0.04, 0.06, 0.08, 0.10, 0.12, 0.14, 0.16, 0.18, 0.20]
    assert camera_to_command_ms(esdf_t, esdf_stamp, safe_t) == pytest.approx([60.0, 60.0])
    assert camera_to_command_ms(esdf_t, esdf_stamp, [0.01]) == []  # no command after either ESDF


def test_content_age_is_measured_from_the_newest_stamp_received() -> None:
    esdf_t, esdf_stamp = [0.05, 0.16], [0.00, 0.10]
    safe_t = [0.04, 0.06, 0.16, 0.18]
    # before any ESDF: nothing; then from stamp 0.00; from 0.16 on (inclusive) from stamp 0.10
    assert content_age_ms(esdf_t, esdf_stamp, safe_t) == pytest.approx([60.0, 60.0, 80.0])
    # an older stamp arriving late does not make the content older
    assert content_age_ms([0.05, 0.06], [0.04, 0.01], [0.07]) == pytest.approx([30.0])
    assert content_age_ms([], [], [0.1]) == []


def test_arrival_age_counts_from_the_newest_esdf_received() -> None:
    assert arrival_age_ms([0.05, 0.16], [0.04, 0.06, 0.16, 0.20]) == pytest.approx([10.0, 0.0, 40.0])
    assert arrival_age_ms([], [0.1]) == []


def test_content_age_from_the_image_counts_from_its_first_publication() -> None:
    # ESDFs (arrival, camera stamp); images (arrival, stamp): stamp 0.10's image published at 0.13.
    esdf = [(0.05, 0.00), (0.16, 0.10)]
    images = [(0.02, 0.00), (0.13, 0.10), (0.14, 0.10)]
    assert content_age_from_image_ms(esdf, images, [0.06, 0.16, 0.18]) == pytest.approx([40.0, 30.0, 50.0])
    # an ESDF whose image was never seen is left out, not counted from its stamp
    assert content_age_from_image_ms([(0.05, 0.00)], [], [0.06]) == []


def test_first_arrival_ignores_republications() -> None:
    assert first_arrivals([(0.30, 0.1), (0.20, 0.1), (0.25, 0.2)]) == {0.1: 0.20, 0.2: 0.25}


def test_pipeline_stages_split_the_delay_and_count_skipped_frames() -> None:
    # Camera frames stamped 0.0, 0.1, 0.2, 0.3; the image arrives 5 ms after its stamp;
    # perception publishes frames 0.0, 0.1 and 0.3 (0.2 superseded) 40 ms later; mapping builds
    # ESDFs of 0.0 and 0.3 (0.1 skipped) 20 ms after that, and re-publishes 0.3 once.
    stamped = {
        "camera/image": [(s + 0.005, s) for s in (0.0, 0.1, 0.2, 0.3)],
        "perception/frame": [(s + 0.045, s) for s in (0.0, 0.1, 0.3)],
        "map/esdf": [(0.065, 0.0), (0.365, 0.3), (0.40, 0.3)],
    }
    st = pipeline_stages(stamped)
    assert st["camera/image"]["from_camera_ms"] == pytest.approx([5.0] * 4)
    assert st["camera/image"]["skipped"] == 0
    assert st["perception/frame"]["from_camera_ms"] == pytest.approx([45.0] * 3)
    assert st["perception/frame"]["hop_ms"] == pytest.approx([40.0] * 3)
    assert st["perception/frame"]["skipped"] == 1
    assert st["map/esdf"]["from_camera_ms"] == pytest.approx([65.0, 65.0])
    assert st["map/esdf"]["hop_ms"] == pytest.approx([20.0, 20.0])
    assert st["map/esdf"]["skipped"] == 2


def test_latency_summary_pairs_commands_with_esdf_stamps_on_a_timeline() -> None:
    # A 10 Hz camera; every frame's ESDF arrives 60 ms after its stamp; the filter steps every
    # 20 ms from 0.01 s. Then camera → first cmd/safe after the ESDF is 70 ms; at each command
    # the content age is 70–150 ms and the arrival age 10–90 ms (a sawtooth of the camera period).
    stamps = [0.1 * i for i in range(10)]
    stamped = {"camera/image": [(s + 0.002, s) for s in stamps],
               "perception/frame": [(s + 0.03, s) for s in stamps],
               "map/esdf": [(s + 0.06, s) for s in stamps]}
    safe_t = [0.01 + 0.02 * i for i in range(50)]
    lat = latency_summary(stamped, safe_t, filter_age_ms=[100.0, 120.0],
                          node_extra={"perception": {"process_ms": [25.0, 27.0]}})
    assert lat["camera_to_cmd_safe_ms"]["median"] == pytest.approx(70.0)
    assert lat["camera_to_cmd_safe_ms"]["n"] == 10
    age, arrival = lat["esdf_content_age_ms"], lat["esdf_arrival_age_ms"]
    assert age["n"] == arrival["n"] == 47  # the commands before the first ESDF have no map
    assert (age["median"], age["max"]) == pytest.approx((110.0, 150.0))
    assert min(content_age_ms([s + 0.06 for s in stamps], stamps, safe_t)) == pytest.approx(70.0)
    # arrival age = content age − the 60 ms the pipeline took
    assert (arrival["median"], arrival["max"]) == pytest.approx((50.0, 90.0))
    assert lat["stages"]["map/esdf"]["from_camera_ms"]["median"] == pytest.approx(60.0)
    assert lat["stages"]["perception/frame"]["skipped"] == 0
    assert lat["esdf_age_ms"]["median"] == pytest.approx(110.0)
    assert lat["work_ms"]["perception process"]["median"] == pytest.approx(26.0)
    assert lat["work_ms"]["simulator render"] is None  # no snapshots: no number, not zero


def test_the_bench_runs_the_demos_camera_services_and_previous_adds_only_its_settings(tmp_path) -> None:
    from riskfield.experiments.benches.latency import PREVIOUS
    from riskfield.experiments.demo.run import DemoConfig, camera_pipeline

    cfg = DemoConfig(out=tmp_path)
    now, previous = camera_pipeline(cfg), camera_pipeline(cfg, PREVIOUS)
    assert [s for _, s, _ in now] == ["simulator", "perception", "mapping", "safety-filter"]
    for (label, service, args), (label_p, service_p, args_p) in zip(now, previous, strict=True):
        assert (label, service) == (label_p, service_p)
        assert args_p == args + PREVIOUS.get(label, [])
    args_of = {label: args for label, _, args in previous}
    assert "esdf_rate_hz=10" in args_of["mapping"] and "step_on_map=false" in args_of["safety-filter"]


def test_timing_stats_one_naming_and_none_for_nothing() -> None:
    from riskfield.experiments.timing import timing_stats

    st = timing_stats([1.0, 2.0, 3.0, 4.0])
    assert st is not None and set(st) == {"n", "median", "p90", "p95", "p99", "mean", "max"}
    assert (st["n"], st["median"], st["mean"], st["max"]) == (4, 2.5, 2.5, 4.0)
    assert timing_stats([]) is None
