"""The renderer's compiled shading pass (``simulator.kernels``) against the numpy reference:
every output array identical, byte for byte, on moving views of a furnished room (hits, misses
through open walls, hits beyond ``max_depth``, several objects and a moving one)."""

from __future__ import annotations

import numpy as np
import pytest

from riskfield.services.simulator.camera import Renderer
from riskfield.services.simulator.kernels import HAVE_NUMBA
from riskfield.services.simulator.scenario import load_scenario
from riskfield.services.simulator.world import World

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")

ROOM = {"room": {"size": [6.0, 5.0]}, "camera": {"width": 160, "height": 120},
        "robot": {"type": "limo", "start": [-1.5, 0.0, 0.0]},
        "objects": [{"class": "animal", "position": [0.5, 0.3]}, {"class": "box", "position": [1.0, -0.8]},
                    {"class": "chair", "position": [2.0, 1.2], "yaw": 1.0},
                    {"class": "person", "position": [0.0, 1.0], "waypoints": [[0.0, 1.0], [0.0, -1.0]],
                     "speed": 0.5}]}


@pytest.mark.parametrize("max_depth", [50.0, 2.0])
def test_compiled_render_is_identical_to_numpy(max_depth: float) -> None:
    world = World(load_scenario(ROOM))
    ref = Renderer(world.camera, max_depth=max_depth, compiled=False)
    fast = Renderer(world.camera, max_depth=max_depth, compiled=True)
    cut = False
    for i in range(8):
        world.command(np.array([0.2, 0.0, 0.0]), np.array([0.0, 0.0, 0.9]))
        world.advance(0.25)
        snap, T_WC = world.snapshot(), world.T_WC()
        a, b = ref.render(snap, T_WC), fast.render(snap, T_WC)
        for name in ("rgb", "depth", "points", "labels", "normals", "object", "T_WC"):
            x, y = getattr(a, name), getattr(b, name)
            assert x.dtype == y.dtype and x.shape == y.shape, name
            np.testing.assert_array_equal(x, y, err_msg=f"frame {i}: {name}")
        cut |= bool((~a.valid).any() and a.valid.any())
    assert cut or max_depth == 50.0  # the cut-off is exercised
    assert len(np.unique(a.object)) >= 3
