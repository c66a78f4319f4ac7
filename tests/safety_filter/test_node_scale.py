"""The safety-filter node under perception's alignment (``perception/alignment``), over a real router:
an unconverged estimate caps the speed and shrinks the distance, and the status says so."""

from __future__ import annotations

import pytest

from riskfield.protocol import Alignment, SafetyStatus, VelocityCommand
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_until

from .test_node import Feeder, grid, latest


def alignment(sigma: float, converged: bool) -> Alignment:
    return Alignment(scale=1.0, rotation=(0.0, 0.0, 0.0, 1.0), translation=(0.0, 0.0, 0.0), scale_sigma=sigma,
                     residual=0.003, pairs=10, baseline=0.2, source="fused", converged=converged)


def test_an_uncertain_map_scale_caps_the_speed_until_it_converges(router_endpoint):
    robot = "t_sf_scale"
    args = ["--robot", robot, "--set", "scale_speed_cap=0.15"]
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/safety-filter"), proc.output
        status = Collector(session, f"rf/{robot}/safety/status", SafetyStatus)
        cmds = Collector(session, f"rf/{robot}/cmd/safe", VelocityCommand)
        with Feeder(session, robot) as feed:
            feed.msgs["map/esdf"] = grid(center=(3.0, 0.0))  # far: the reference passes unfiltered
            assert wait_until(lambda: latest(status) is not None and latest(status).fallback is None, 10)
            assert not latest(status).scale_uncertain and latest(status).speed_cap is None
            put(session, f"rf/{robot}/perception/alignment", alignment(0.05, False))
            assert wait_until(lambda: latest(status).scale_uncertain, 10), latest(status)
            st = latest(status)
            assert st.speed_cap == pytest.approx(0.15) and st.distance_margin > 0.006, st  # k·σ·d + k·residual
            cmds.clear()
            assert wait_until(lambda: len(cmds.items) >= 5, 5)
            assert max(c.linear[0] for c in cmds.items[-3:]) <= 0.15 + 1e-9
            put(session, f"rf/{robot}/perception/alignment", alignment(0.004, True))
            assert wait_until(lambda: not latest(status).scale_uncertain, 10), latest(status)
            assert latest(status).speed_cap is None and latest(status).distance_margin < 0.05
            cmds.clear()
            assert wait_until(lambda: len(cmds.items) >= 5 and cmds.items[-1].linear[0] > 0.5, 5)
        assert proc.stop() == 0
        status.close()
        cmds.close()
