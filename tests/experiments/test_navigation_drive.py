"""The navigation experiment's goal-following, shared by the demo and `riskfield bench navigation`:
over a real router, a robot (this test) that moves only once it has its goal."""

from __future__ import annotations

import threading

import numpy as np

from riskfield.experiments.navigation import as_waypoints, drive, place_unseen
from riskfield.experiments.stack import publish, recording
from riskfield.protocol import Keys, NavGoal, RobotState
from riskfield.services.runtime.processes import EmbeddedRouter, client_session
from riskfield.testing import Collector


def _state(x: float, y: float) -> RobotState:
    return RobotState(position=(x, y, 0.0), orientation=(0.0, 0.0, 0.0, 1.0), linear_velocity=(0.0, 0.0, 0.0),
                      angular_velocity=(0.0, 0.0, 0.0))


def test_as_waypoints_lifts_planar_points():
    w = as_waypoints([(1.0, 2.0), (3.0, 4.0)])
    np.testing.assert_array_equal(w, [[1.0, 2.0, 0.0], [3.0, 4.0, 0.0]])
    np.testing.assert_array_equal(as_waypoints(w), w)


def test_drive_completes_on_the_recorded_states_and_reports_each_waypoint():
    keys = Keys(robot="t_drive")
    corners = [(1.0, 0.0), (1.0, 1.0)]
    reached: list[int] = []
    with EmbeddedRouter() as router, client_session(router.endpoint) as s, \
            recording(s, {"state": (keys.state, RobotState)}) as rec:
        goals = Collector(s, keys.nav_goal, NavGoal)
        spawns = Collector(s, keys.sim_spawn)
        stop = threading.Event()

        def robot() -> None:
            """Drive straight through the corners once a goal has arrived (0.05 m steps)."""
            goals.wait(1, timeout_s=30)
            path = np.vstack([np.linspace((0.0, 0.0), corners[0], 21), np.linspace(corners[0], corners[1], 21)])
            for x, y in path:
                if stop.is_set():
                    return
                publish(s, keys.state, _state(float(x), float(y)))
                stop.wait(0.02)

        def on_reached(n: int) -> None:
            reached.append(n)
            if n == 1:
                place_unseen(s, keys, {"class": "ball", "name": "unseen_ball", "position": [1.0, 0.5]})

        t = threading.Thread(target=robot, daemon=True)
        t.start()
        try:
            result = drive(s, keys, rec, corners, tolerance=0.2, timeout_s=60, on_reached=on_reached)
        finally:
            stop.set()
            t.join(5)
        spawned = spawns.wait(1, timeout_s=10)
        goals.close()
        spawns.close()
    assert result.completed and result.reached == 2 and result.lap_time_s is not None
    assert reached == [1, 2]
    np.testing.assert_array_equal(goals.items[0].waypoints, as_waypoints(corners))
    assert goals.items[0].tolerance == 0.2 and goals.items[0].loop is False
    assert b"unseen_ball" in spawned[0]


def test_drive_times_out_when_the_robot_never_moves():
    keys = Keys(robot="t_drive_still")
    with EmbeddedRouter() as router, client_session(router.endpoint) as s, \
            recording(s, {"state": (keys.state, RobotState)}) as rec:
        result = drive(s, keys, rec, [(1.0, 0.0)], tolerance=0.2, timeout_s=0.5)
    assert not result.completed and result.reached == 0 and result.lap_time_s is None
