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
