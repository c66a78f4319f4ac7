"""Waypoint sequencing and the navigator core: stop at the last waypoint, loop, staleness."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskfield.services.geometry.transforms import world_to_body
from riskfield.services.navigator import Navigator, NavigatorConfig, WaypointSequencer

SQUARE = np.array([[1.0, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 0]])


def test_sequence_advances_and_finishes():
    s = WaypointSequencer()
    s.set_goal(SQUARE, 0.1, loop=False)
    assert s.update(np.array([0.0, 0, 0])) is not None and s.index == 0
    for i, w in enumerate(SQUARE[:-1]):
        target = s.update(w + 0.05)
        np.testing.assert_array_equal(target, SQUARE[i + 1])
    assert s.update(SQUARE[-1]) is None
    assert s.finished and s.reached == 4 and s.laps == 0


def test_loop_wraps_around_and_counts_laps():
    s = WaypointSequencer()
    s.set_goal(SQUARE, 0.1, loop=True)
    for _ in range(2):
        for w in SQUARE:
            s.update(w)
    assert s.laps == 2 and s.index == 0 and s.active


def test_loop_with_all_waypoints_inside_tolerance_terminates():
    s = WaypointSequencer()
    s.set_goal(np.zeros((3, 3)), 0.5, loop=True)
    assert s.update(np.zeros(3)) is not None
    assert s.laps == 1


def test_planar_ignores_height_but_3d_does_not():
    w = np.array([[1.0, 1.0, 2.0]])
    planar, spatial = WaypointSequencer(planar=True), WaypointSequencer(planar=False)
    planar.set_goal(w, 0.1, False)
    spatial.set_goal(w, 0.1, False)
    assert planar.update(np.array([1.0, 1.0, 0.0])) is None
    assert spatial.update(np.array([1.0, 1.0, 0.0])) is not None


@pytest.mark.parametrize("bad", [np.zeros((0, 3)), np.array([[np.nan, 0, 0]])])
def test_bad_goals_are_rejected(bad):
    with pytest.raises(ValueError):
        WaypointSequencer().set_goal(bad, 0.1, False)


def run_unicycle(nav: Navigator, p: np.ndarray, yaw: float, steps: int, dt: float = 0.05):
    t = 0.0
    path, reasons = [p.copy()], []
    for _ in range(steps):
        q = [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]
        nav.set_state(np.array([p[0], p[1], 0.0]), q, np.zeros(3), t)
        cmd = nav.step(t)
        reasons.append(cmd.reason)
        v, w = cmd.linear[0], cmd.angular[2]
        p = p + dt * v * np.array([math.cos(yaw), math.sin(yaw)])
        yaw += dt * w
        t += dt
        path.append(p.copy())
    return np.array(path), reasons


def test_navigator_drives_the_square_and_stops_at_the_last_waypoint():
    nav = Navigator()
    nav.set_goal(SQUARE, 0.08, loop=False)
    path, reasons = run_unicycle(nav, np.array([0.0, -0.3]), 0.0, 800)
    assert reasons[-1] == "arrived"
    assert nav.sequencer.reached == 4
    assert np.linalg.norm(path[-1] - SQUARE[-1, :2]) < 0.08 + 0.03
    # After arrival the robot no longer moves.
    k = reasons.index("arrived")
    assert np.allclose(path[k + 1:], path[k + 1])
    # It passed near every corner.
    for w in SQUARE[:, :2]:
        assert np.min(np.linalg.norm(path - w, axis=1)) < 0.09


def test_navigator_loops_forever_when_asked():
    nav = Navigator()
    nav.set_goal(SQUARE, 0.08, loop=True)
    _, reasons = run_unicycle(nav, np.array([0.0, 0.0]), 0.0, 1500)
    assert "arrived" not in reasons
    assert nav.sequencer.laps >= 2


def test_stale_state_commands_zero():
    nav = Navigator(NavigatorConfig(state_timeout_s=0.2))
    nav.set_goal(SQUARE, 0.05, loop=False)
    assert nav.step(0.0).reason == "stale_state"  # no state at all
    nav.set_state([0.0, 0.0, 0.0], [0, 0, 0, 1], [0, 0, 0], t=1.0)
    assert nav.step(1.1).reason == "driving"
    cmd = nav.step(1.3)
    assert cmd.reason == "stale_state" and cmd.is_zero


def test_idle_without_goal():
    nav = Navigator()
    nav.set_state([0.0, 0.0, 0.0], [0, 0, 0, 1], [0, 0, 0], t=0.0)
    cmd = nav.step(0.0)
    assert cmd.reason == "idle" and cmd.is_zero


def test_double_integrator_mode_commands_body_frame_velocity_towards_goal():
    nav = Navigator(NavigatorConfig(model="double_integrator", v_max=0.5))
    nav.set_goal(np.array([[2.0, 0.0, 1.0]]), 0.05, loop=False)
    yaw = math.pi / 2  # body x points to world +y
    nav.set_state([0.0, 0.0, 1.0], [0, 0, math.sin(yaw / 2), math.cos(yaw / 2)], np.zeros(3), 0.0)
    cmd = nav.step(0.0)
    # World +x is body −y for this heading.
    np.testing.assert_allclose(cmd.linear, [0.0, -0.5, 0.0], atol=1e-9)


def test_double_integrator_navigation_reaches_3d_waypoints():
    nav = Navigator(NavigatorConfig(model="double_integrator"))
    wps = np.array([[1.0, 0.0, 0.5], [1.0, 1.0, 1.0]])
    nav.set_goal(wps, 0.05, loop=False)
    p, v, t, dt = np.zeros(3), np.zeros(3), 0.0, 0.02
    for _ in range(1500):
        nav.set_state(p, [0, 0, 0, 1], v, t)
        cmd = nav.step(t)
        v = np.array(cmd.linear)  # a velocity-tracking vehicle
        p, t = p + dt * v, t + dt
    assert nav.sequencer.finished
    assert np.linalg.norm(p - wps[-1]) < 0.06


def test_world_to_body_inverts_rotation():
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        v = rng.normal(size=3)
        assert abs(np.linalg.norm(world_to_body(q, v)) - np.linalg.norm(v)) < 1e-9


def drive_with_blocking_filter(nav: Navigator, steps: int, dt: float = 0.05) -> tuple[np.ndarray, list[str]]:
    """A unicycle whose 'safety filter' zeroes any motion that would bring it closer than
    0.45 m to (1, 0) (moving along or away is allowed): the head-on deadlock of a CBF-filtered CLF."""
    p, yaw, t = np.array([0.0, 0.0]), 0.0, 0.0
    reasons = []
    for _ in range(steps):
        nav.set_state([p[0], p[1], 0.0], [0, 0, math.sin(yaw / 2), math.cos(yaw / 2)], np.zeros(3), t)
        cmd = nav.step(t)
        reasons.append(cmd.reason)
        v, w = cmd.linear[0], cmd.angular[2]
        nxt = p + dt * v * np.array([math.cos(yaw), math.sin(yaw)])
        d_new, d_old = np.linalg.norm(nxt - [1.0, 0.0]), np.linalg.norm(p - [1.0, 0.0])
        if d_new < 0.45 and d_new < d_old:
            nxt = p  # blocked
        p, yaw, t = nxt, yaw + dt * w, t + dt
    return p, reasons


def test_escape_gets_round_a_head_on_obstacle():
    goal = np.array([[2.0, 0.0, 0.0]])
    stuck = Navigator(NavigatorConfig(escape=False))
    stuck.set_goal(goal, 0.1, loop=False)
    p, _ = drive_with_blocking_filter(stuck, 1200)
    assert p[0] < 0.6 and not stuck.sequencer.finished  # the deadlock is real

    nav = Navigator(NavigatorConfig(escape=True))
    nav.set_goal(goal, 0.1, loop=False)
    p, reasons = drive_with_blocking_filter(nav, 1200)
    assert nav.escapes >= 1
    assert nav.sequencer.finished and reasons[-1] == "arrived"
    assert np.linalg.norm(p - goal[0, :2]) < 0.15


def test_no_escape_on_a_free_path():
    nav = Navigator()
    nav.set_goal(SQUARE, 0.08, loop=False)
    run_unicycle(nav, np.array([0.0, -0.3]), 0.0, 800)
    assert nav.escapes == 0 and nav.sequencer.finished
