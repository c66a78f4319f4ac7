"""The teleop experiment's parts shared by the demo and `riskfield bench teleop`."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from riskfield.experiments.stack import publish
from riskfield.experiments.teleop import approach, first_intervention, is_intervention, wait_operator_done
from riskfield.protocol import Keys, NodeStatus, SafetyStatus
from riskfield.services.runtime.processes import EmbeddedRouter, client_session


def test_an_intervention_is_a_cbf_correction_not_a_brake():
    assert is_intervention(SafetyStatus(h=0.2, risk_group=1, intervening=True, fallback=None, solve_us=5.0,
                                        esdf_age_ms=10.0))
    assert not is_intervention(SafetyStatus(h=0.2, risk_group=1, intervening=True, fallback="stale_map",
                                            solve_us=5.0, esdf_age_ms=10.0))
    assert not is_intervention(SafetyStatus(h=0.2, risk_group=1, intervening=False, fallback=None, solve_us=5.0,
                                            esdf_age_ms=10.0))


def test_approach_metrics():
    t = np.array([0.0, 1.0, 2.0])
    d = np.array([2.0, 1.0, 0.4])
    assert approach(t, d, 0.5) == (pytest.approx(1.5), pytest.approx(0.4))
    assert approach(t, d, None) == (None, pytest.approx(0.4))
    assert first_intervention(t, np.array([0, 1, 1], bool)) == 1.0


def test_wait_operator_done_follows_the_operator_status_counter():
    keys = Keys(robot="t_op_done")
    with EmbeddedRouter() as router, client_session(router.endpoint) as s:
        stop = threading.Event()

        def operator() -> None:  # the operator node's status: target_index counts visited targets
            for i in range(200):
                if stop.is_set():
                    return
                publish(s, keys.status("operator"), NodeStatus(service="operator", extra={"target_index": i // 10}))
                stop.wait(0.02)

        t = threading.Thread(target=operator, daemon=True)
        t.start()
        try:
            assert wait_operator_done(s, keys, 2, timeout_s=30)
            assert not wait_operator_done(s, keys, 1000, timeout_s=0.5)
        finally:
            stop.set()
            t.join(5)


def test_the_paper_preset_is_the_papers_look_ahead_filter(tmp_path, monkeypatch):
    """``--preset paper`` (what `riskfield bench teleop --preset paper` passes to the node): one CBF row at
    the look-ahead point with h = d(p_L) (no body discs, no radius, no extra margin), the trilinear field,
    no predictive rows; anything the config file, environment or --set gives still wins."""
    from riskfield.experiments.benches.teleop import filter_args
    from riskfield.protocol import RiskConfig
    from riskfield.services.fields import AnalyticField
    from riskfield.services.geometry.shapes import Plane
    from riskfield.services.runtime.settings import parse_overrides
    from riskfield.services.safety_filter import FilterState, SafetyFilter
    from riskfield.services.safety_filter.settings import FilterSettings

    args = filter_args("paper")
    assert args[-2:] == ["--set", "preset=paper"] and filter_args(None) == args[:-2]
    s = FilterSettings(**parse_overrides([a for a in args if a != "--set"]))
    assert s.model == "unicycle" and s.body().shape == "none" and s.robot_radius == 0.0
    assert s.predictive_rows is False and s.interpolation == "trilinear"
    default = FilterSettings()
    assert default.body().shape == "rectangle" and default.robot_radius == 0.15
    filt = SafetyFilter(s.filter_config(), RiskConfig(), warm_up=False)
    assert filt.delta == 0.0 and filt.model.m == 1  # the look-ahead point alone
    # At 0.6 m from a wall the look-ahead point is at d = 0.6 - L: h is that distance, nothing subtracted.
    wall = AnalyticField([Plane((-1.0, 0.0, 0.0), -1.0, 0)])
    res = filt.filter(FilterState(np.array([0.4, 0.0, 0.0])), np.array([0.5, 0.0]), wall)
    assert res.h == pytest.approx(1.0 - 0.4 - s.lookahead_m, abs=1e-9)
    # explicit settings override the preset (a config file, here through the environment)
    cfg = tmp_path / "filter.yaml"
    cfg.write_text("safety-filter:\n  robot_radius: 0.1\n")
    monkeypatch.setenv("RISKFIELD_CONFIG", str(cfg))
    assert FilterSettings(preset="paper").robot_radius == 0.1
    monkeypatch.delenv("RISKFIELD_CONFIG")
    with pytest.raises(ValueError, match="preset 'papr' is not one of"):
        FilterSettings(preset="papr")
