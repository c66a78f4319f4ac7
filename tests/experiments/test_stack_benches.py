"""Teleop and navigation benchmarks: their pure metric helpers, and the navigator driving the
full service stack (simulator → perception relay → mapping → safety filter) over Zenoh."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskfield.experiments.navigation import polyline_distance
from riskfield.experiments.scenarios import (
    SQUARE_CORNERS,
    SQUARE_ROOM,
    SQUARE_UNSEEN,
    obstacle_distance,
    risky_clearance,
)
from riskfield.experiments.stack import FAST_FILTER, Stack, perception_args, recording
from riskfield.experiments.teleop import Trace, operator_args
from riskfield.protocol import NavGoal, RobotState, SafetyStatus
from riskfield.testing import put, wait_until


def test_polyline_distance_of_the_square():
    pts = np.array([[2.0, 0.0], [0.0, 0.0], [2.5, 2.5], [-2.0, -1.0]])
    np.testing.assert_allclose(polyline_distance(pts, SQUARE_CORNERS), [0.0, 2.0, math.hypot(0.5, 0.5), 0.0])
    # planar corners, open end: the closing side counts too
    np.testing.assert_allclose(polyline_distance(np.array([[-1.0, 0.0]]), SQUARE_CORNERS[:, :2]), [1.0])


def test_teleop_ground_truth_distance_and_metrics():
    dist = obstacle_distance("teleop_ball", "ball")
    d = dist(np.array([[0.0, 0.0], [0.5, 1.0]]))
    r = 0.12  # the ball's default size 0.24
    np.testing.assert_allclose(d, [0.5 - r, 1.0 - r], atol=0.01)
    t = np.linspace(0, 4, 5)
    tr = Trace(t, np.array([3.0, 2.0, 1.0, 0.8, 1.5]), np.array([2.8, 1.8, 0.8, 0.55, 1.2]),
               t, t, t, t, t, t, t_intervention=1.5)
    m = tr.metrics()
    assert m["first_intervention_m"] == pytest.approx(1.3)  # interpolated between the states at 1 s and 2 s
    assert m["first_intervention_centre_m"] == pytest.approx(1.5)
    assert m["min_clearance_m"] == pytest.approx(0.55)
    assert m["min_clearance_centre_m"] == pytest.approx(0.8)
    none = Trace(t, t + 1, t + 1, t, t, t, t, t, t, None).metrics()
    assert none["first_intervention_m"] is None and none["min_clearance_m"] == 1.0


def test_navigation_clearance_includes_the_unseen_obstacle(tmp_path):
    import yaml

    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(SQUARE_ROOM))
    p = np.array([[2.0, -0.5]])
    with_ball, without = risky_clearance(path, [SQUARE_UNSEEN])(p)[0], risky_clearance(path)(p)[0]
    assert with_ball == pytest.approx(0.5 - 0.12, abs=0.02)
    assert without > 0.5


def test_operator_args_are_what_the_operator_service_reads():
    from riskfield.services.operator.node import OperatorSettings
    from riskfield.services.runtime import parse_overrides

    args = operator_args([("ball", -1.4, -1.5), ("dog", -2.7, 1.5)], seed=3, push_s=6.0)
    sets = parse_overrides(args[1::2])
    s = OperatorSettings.model_validate(sets)
    assert s.targets == [("ball", -1.4, -1.5), ("dog", -2.7, 1.5)] and s.seed == 3 and s.push_s == 6.0


def test_perception_modes():
    assert perception_args("gt")[0] == "relay"
    assert perception_args("sim")[0] == "perception"
    with pytest.raises(ValueError):
        perception_args("lidar")


@pytest.mark.slow
def test_navigator_drives_the_full_stack_round_a_ball():
    """Goal straight behind the ball: the navigator's reference, filtered on the live semantic
    ESDF, gets the LIMO to the goal without touching the ball (ground truth)."""
    with Stack(robot="t_nav_stack") as stack:
        service, args = perception_args("gt")
        stack.start("sim", "simulator", ["--set", "scenario=teleop_ball", "--set", "camera_hz=10"])
        stack.start("perception", service, args)
        stack.start("mapping", "mapping", ["--set", "esdf_rate_hz=10"])
        stack.start("filter", "safety-filter", FAST_FILTER)
        stack.start("navigator", "navigator", ["--set", "nav.v_max=0.5"])
        keys = {"state": (stack.keys.state, RobotState), "status": (stack.keys.safety_status, SafetyStatus)}
        goal = np.array([[1.5, 0.0, 0.0]])  # the ball sits at (0.5, 0) on the straight line from (-3, 0)
        with recording(stack.session, keys) as rec:
            # The goal is sent once the first ESDF has reached the filter (the stack is up).
            assert wait_until(lambda: any(s.esdf_age_ms >= 0 for _, s in rec.snapshot("status")), 60.0), \
                stack.procs["filter"].output[-2000:]
            put(stack.session, stack.keys.nav_goal, NavGoal(waypoints=goal, tolerance=0.2, loop=False))

            def arrived() -> bool:
                s = rec.snapshot("state")
                return bool(s) and math.hypot(s[-1][1].position[0] - 1.5, s[-1][1].position[1]) < 0.25

            assert wait_until(arrived, 60.0), stack.procs["navigator"].output[-2000:]
            states = rec.snapshot("state")
            status = rec.snapshot("status")
        xy = np.array([m.position[:2] for _, m in states])
        clearance = obstacle_distance("teleop_ball", "ball")(xy)
        assert clearance.min() > 0.15  # the LIMO's radius: never touched the ball
        assert any(s.intervening and s.fallback is None for _, s in status)  # the filter did act
        for label in list(stack.procs):
            assert stack.stop(label) == 0
