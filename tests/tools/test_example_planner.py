"""The external-planner example: plans around inflated obstacles, and runs against a live ESDF key."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from riskfield.protocol import EsdfGrid, NavGoal
from riskfield.testing import Collector, client_session, put

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "esdf_planner.py"


def _load():
    import importlib.util

    spec = importlib.util.spec_from_file_location("esdf_planner", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _wall_grid() -> EsdfGrid:
    """A 4 m x 2 m slice at 5 cm with a wall segment across x = 2 m for y < 1.4 m."""
    vs = 0.05
    xs, ys = np.arange(81) * vs, np.arange(41) * vs
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    # distance to the segment x = 2, y in [0, 1.4]
    dy = np.maximum(Y - 1.4, 0.0)
    d = np.hypot(X - 2.0, dy) - 0.05
    return EsdfGrid(origin=(0, 0, 0), voxel_size=vs, distance=d[:, :, None], risk_group=np.ones((81, 41, 1), np.uint8),
                    groups=["high", "mid", "low"], max_distance=2.0, unknown_is_occupied=False)


def test_plan_keeps_clearance_and_goes_around_the_wall():
    mod = _load()
    grid = _wall_grid()
    path = mod.plan(grid, (0.5, 0.5), (3.5, 0.5), clearance=0.2)
    assert path is not None
    np.testing.assert_allclose(path[0], [0.5, 0.5]) and np.testing.assert_allclose(path[-1], [3.5, 0.5])
    i = np.round(path / grid.voxel_size).astype(int)
    assert np.all(grid.distance[i[:, 0], i[:, 1], 0] >= 0.2)
    assert path[:, 1].max() > 1.4 + 0.2  # it had to go over the end of the wall
    assert mod.plan(grid, (0.5, 0.5), (3.5, 0.5), clearance=0.9) is None  # the gap is too narrow
    assert mod.plan(grid, (2.0, 0.5), (3.5, 0.5), clearance=0.2) is None  # start inside the wall
    # within half a voxel beyond the outer voxel centres: outside the map (the filter's rule)
    assert mod.plan(grid, (-0.02, 0.5), (3.5, 0.5), clearance=0.2) is None
    assert mod.plan(grid, (0.0, 0.5), (3.5, 0.5), clearance=0.2) is not None
    wps = mod.simplify(path, every=5)
    np.testing.assert_allclose(wps[-1], path[-1])


def test_example_script_over_zenoh(router_endpoint):
    grid = _wall_grid()
    stop = threading.Event()
    with client_session(router_endpoint) as s:
        goals = Collector(s, "rf/t_plan/nav/goal", NavGoal)

        def publish() -> None:
            while not stop.is_set():
                put(s, "rf/t_plan/map/esdf", grid)
                time.sleep(0.1)  # mapping's periodic ESDF (scenario): the script subscribes whenever it starts

        t = threading.Thread(target=publish, daemon=True)
        t.start()
        try:
            r = subprocess.run([sys.executable, str(EXAMPLE), "--connect", router_endpoint, "--robot", "t_plan",
                                "--start", "0.5", "0.5", "--goal", "3.5", "0.5", "--send-goal"],
                               capture_output=True, text=True, timeout=60)
        finally:
            stop.set()
            t.join()
        assert r.returncode == 0, r.stderr
        out = json.loads(r.stdout)
        assert out["waypoints"][-1] == [3.5, 0.5]
        goal = goals.wait(1)[0]
        np.testing.assert_allclose(goal.waypoints[-1], [3.5, 0.5, 0.0])
        goals.close()
