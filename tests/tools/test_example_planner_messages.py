"""The planner example says why it cannot plan: an end outside the map (naming the map's
bounds, the filter's in-map rule) or too close to an obstacle, instead of a generic "no path"."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from riskfield.protocol import EsdfGrid
from riskfield.testing import client_session, put

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "esdf_planner.py"


def _load():
    import importlib.util

    spec = importlib.util.spec_from_file_location("esdf_planner_messages", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _open_grid() -> EsdfGrid:
    """2 m × 1 m at 0.1 m from (−0.5, 0): one obstacle cell at (0.5, 0.5)."""
    vs = 0.1
    X, Y = np.meshgrid(-0.5 + np.arange(21) * vs, np.arange(11) * vs, indexing="ij")
    d = np.hypot(X - 0.5, Y - 0.5) - 0.05
    return EsdfGrid(origin=(-0.5, 0, 0), voxel_size=vs, distance=d[:, :, None].astype(np.float32),
                    risk_group=np.ones((21, 11, 1), np.uint8), groups=["high", "mid", "low"], max_distance=2.0,
                    unknown_is_occupied=False)


def test_bounds_and_reasons():
    mod = _load()
    g = _open_grid()
    (x0, x1), (y0, y1) = mod.bounds(g)
    np.testing.assert_allclose([x0, x1, y0, y1], [-0.5, 1.5, 0.0, 1.0])  # the outer voxel centres
    why = mod.unplannable(g, (0.0, 0.2), (3.0, 1.0), clearance=0.2)
    assert why is not None and "goal (3, 1) is outside the map" in why and "-0.50..1.50" in why and "0.00..1.00" in why
    why = mod.unplannable(g, (0.0, -0.5), (1.0, 0.2), clearance=0.2)
    assert why is not None and why.startswith("the start (0, -0.5) is outside the map")
    why = mod.unplannable(g, (0.5, 0.5), (1.2, 0.2), clearance=0.2)
    assert why is not None and "start (0.5, 0.5) is 0.01 m from an obstacle" in why  # as the filter reads it
    assert mod.unplannable(g, (-0.3, 0.2), (1.3, 0.8), clearance=0.2) is None
    assert mod.plan(g, (-0.3, 0.2), (1.3, 0.8), clearance=0.2) is not None


def test_script_names_the_map_bounds_for_a_goal_outside_them(router_endpoint):
    grid = _open_grid()
    stop = threading.Event()
    with client_session(router_endpoint) as s:
        def publish() -> None:
            while not stop.is_set():
                put(s, "rf/t_plan_msg/map/esdf", grid)
                time.sleep(0.1)

        t = threading.Thread(target=publish, daemon=True)
        t.start()
        try:
            r = subprocess.run([sys.executable, str(EXAMPLE), "--connect", router_endpoint, "--robot", "t_plan_msg",
                                "--start", "0", "0.2", "--goal", "3", "1"], capture_output=True, text=True, timeout=60)
        finally:
            stop.set()
            t.join()
    assert r.returncode == 1
    assert "goal (3, 1) is outside the map, which covers x -0.50..1.50 m and y 0.00..1.00 m" in r.stderr, r.stderr
    assert "clearance" not in r.stderr
