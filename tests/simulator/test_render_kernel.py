"""The renderer's compiled shading pass (``simulator.kernels``) against its numpy rendering
(``oracles.sim_camera``): every output array identical, byte for byte, on moving views of a
furnished room (hits, misses through open walls, hits beyond ``max_depth``, several objects and a
moving one) and of an empty scene."""

from __future__ import annotations

import numpy as np
import pytest

from oracles.sim_camera import render
from riskfield.services.runtime import jit
from riskfield.services.simulator.camera import Render, Renderer
from riskfield.services.simulator.scenario import load_scenario
from riskfield.services.simulator.scene import Scene
from riskfield.services.simulator.world import World

ROOM = {"room": {"size": [6.0, 5.0]}, "camera": {"width": 160, "height": 120},
        "robot": {"type": "limo", "start": [-1.5, 0.0, 0.0]},
        "objects": [{"class": "animal", "position": [0.5, 0.3]}, {"class": "box", "position": [1.0, -0.8]},
                    {"class": "chair", "position": [2.0, 1.2], "yaw": 1.0},
                    {"class": "person", "position": [0.0, 1.0], "waypoints": [[0.0, 1.0], [0.0, -1.0]],
                     "speed": 0.5}]}


def assert_same_bytes(a: Render, b: Render, frame: int) -> None:
    for name in ("rgb", "depth", "points", "labels", "normals", "object", "T_WC"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert x.tobytes() == y.tobytes(), f"frame {frame}: {name}"  # -0.0 ≠ 0.0 here


@pytest.mark.parametrize("max_depth", [50.0, 2.0])
def test_compiled_render_is_identical_to_numpy(max_depth: float) -> None:
    world = World(load_scenario(ROOM))
    renderer = Renderer(world.camera, max_depth=max_depth)
    cut = False
    for i in range(8):
        world.command(np.array([0.2, 0.0, 0.0]), np.array([0.0, 0.0, 0.9]))
        world.advance(0.25)
        snap, T_WC = world.snapshot(), world.T_WC()
        a, b = render(renderer, snap, T_WC), renderer.render(snap, T_WC)
        assert_same_bytes(a, b, i)
        cut |= bool((~a.valid).any() and a.valid.any())
    assert cut or max_depth == 50.0  # the cut-off is exercised
    assert len(np.unique(a.object)) >= 3


def test_an_empty_scene_renders_like_numpy() -> None:
    """Nothing to cast at: every ray misses (black, zero depth, ``NO_LABEL``, object −1)."""
    world = World(load_scenario(ROOM))
    renderer = Renderer(world.camera)
    snap, T_WC = Scene().at(0.0), world.T_WC()
    assert snap.empty
    b = renderer.render(snap, T_WC)
    assert_same_bytes(render(renderer, snap, T_WC), b, 0)
    assert not b.valid.any() and not b.rgb.any() and (b.object == -1).all()


def test_without_numba_the_renderer_names_what_to_install(monkeypatch):
    monkeypatch.setattr(jit, "HAVE_NUMBA", False)  # an install without numba
    with pytest.raises(ModuleNotFoundError) as info:
        Renderer()
    assert info.value.name == "numba"
