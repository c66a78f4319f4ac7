"""The demo report's camera → cmd/safe latency and ESDF content age, from stamps and receive times."""

from __future__ import annotations

import pytest

from riskfield.experiments.demo.report import camera_to_command_ms, content_age_ms


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
