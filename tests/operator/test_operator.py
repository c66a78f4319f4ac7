"""The scripted operator: reaches towards each target, backs off, is reproducible yet varied."""

from __future__ import annotations

import math

import numpy as np

from riskfield.protocol import RobotState, VelocityCommand
from riskfield.services.operator import OperatorConfig, ScriptedOperator, Target
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_until


def _drive(op: ScriptedOperator, t_end: float = 30.0, dt: float = 0.05, stop_at: float = 0.0):
    """Exact unicycle integration; a wall of 'stop_at' metres around targets stands in for a filter."""
    x = y = yaw = 0.0
    log = []
    for i in range(int(t_end / dt)):
        t = i * dt
        v, w, phase = op.command(t, x, y, yaw)
        tgt = op.target
        if tgt is not None and v > 0 and math.hypot(tgt.x - x, tgt.y - y) < stop_at:
            v = 0.0
        x += v * math.cos(yaw) * dt
        y += v * math.sin(yaw) * dt
        yaw += w * dt
        log.append((t, x, y, yaw, v, w, phase, op.index))
    return log


TARGETS = [Target("ball", 3.0, 0.0), Target("dog", 0.0, 3.0)]


def test_operator_approaches_each_target_then_finishes():
    op = ScriptedOperator(TARGETS, OperatorConfig(push_s=10.0), seed=3)
    log = _drive(op, 50.0, stop_at=0.5)
    phases = [r[6] for r in log]
    assert phases[-1] == "done"
    for k, tgt in enumerate(TARGETS):
        rows = [r for r in log if r[7] == k and r[6] == "approach"]
        d = [math.hypot(tgt.x - r[1], tgt.y - r[2]) for r in rows]
        assert d[-1] < 0.7 and d[-1] < d[0] - 1.0  # it got close to this target
    backoffs = [r for r in log if r[6] == "backoff"]
    assert all(r[4] <= 0 for r in backoffs) and sum(r[4] < 0 for r in backoffs) > 10
    assert all(abs(r[5]) <= 1.2 + 0.7 for r in log)  # stick limits plus noise


def test_same_seed_same_run_other_seed_other_run():
    a = _drive(ScriptedOperator(TARGETS, seed=1), 10.0)
    b = _drive(ScriptedOperator(TARGETS, seed=1), 10.0)
    c = _drive(ScriptedOperator(TARGETS, seed=2), 10.0)
    assert a == b
    assert not np.allclose([r[1:3] for r in a], [r[1:3] for r in c])


def test_no_targets_means_no_motion():
    op = ScriptedOperator([], seed=0)
    assert op.command(0.0, 0, 0, 0)[:2] == (0.0, 0.0)


def test_operator_node_publishes_references(router_endpoint):
    args = ["--robot", "t_op", "--set", "targets=[[ball, 2.0, 0.0]]", "--set", "seed=4"]
    with ServiceProcess("operator", router_endpoint, args) as op, client_session(router_endpoint) as s:
        assert wait_alive(s, "rf/t_op/alive/operator"), op.output
        refs = Collector(s, "rf/t_op/cmd/ref/operator", VelocityCommand)
        first = refs.wait(2)
        assert all(r.linear == (0, 0, 0) and r.angular == (0, 0, 0) for r in first[:2])  # no state yet: zero
        refs.clear()
        state = RobotState(position=(0, 0, 0), orientation=(0, 0, 0, 1), linear_velocity=(0, 0, 0),
                           angular_velocity=(0, 0, 0))
        # A state stream at ~20 Hz, as the simulator sends it, until the operator drives.
        assert wait_until(lambda: (put(s, "rf/t_op/state", state), any(r.linear[0] > 0.1 for r in refs.items))[1],
                          10.0, period_s=0.05), op.output  # facing the ball already: it drives forward
        got = list(refs.items)
        assert got and all(r.source == "operator" for r in got)
        assert op.stop() == 0
        refs.close()
