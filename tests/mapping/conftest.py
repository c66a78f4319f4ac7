"""Shared scenes for the mapping tests: analytic primitives rendered as pointmaps."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

from riskfield.protocol import EsdfGrid, ade20k
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Plane, render
from riskfield.services.geometry.transforms import look_at
from riskfield.services.mapping.mapper import Mapper

WALL = ade20k.index("wall")
FLOOR = ade20k.index("floor")
PERSON = ade20k.index("person")
CHAIR = ade20k.index("chair")


@pytest.fixture
def room() -> list:
    """A wall 1.5 m ahead, the floor, a person-box to the right and a chair-box to the left."""
    return [
        Plane((1, 0, 0), 1.5, WALL),
        Plane((0, 0, 1), 0.0, FLOOR),
        Box((0.8, -0.7, 0.0), (1.0, -0.4, 1.2), PERSON),
        Box((0.9, 0.4, 0.0), (1.1, 0.7, 0.5), CHAIR),
    ]


@pytest.fixture
def small_camera() -> PinholeCamera:
    """A small camera (fast tests) with the angular resolution of the real one at half size."""
    return PinholeCamera.centred(160, 120, 125.0)


Sweep = Callable[[list[Mapper], list, np.ndarray, float], Iterator[list[EsdfGrid]]]


@pytest.fixture
def sweep() -> Sweep:
    """A camera sweeping a scene (128×96, one pose per angle of ``angles``, swaying ``sway`` m
    sideways): each frame integrated into every mapper, then their 3-D grids, one list per frame."""
    cam = PinholeCamera.centred(128, 96, 100.0)
    K = (cam.fx, cam.fy, cam.cx, cam.cy)

    def run(mappers: list[Mapper], scene: list, angles: np.ndarray, sway: float) -> Iterator[list[EsdfGrid]]:
        for i, a in enumerate(angles):
            T = look_at(np.array([0.0, sway * np.sin(a), 0.5]), np.array([1.5, np.sin(a), 0.3]))
            pts, conf, lab = render(scene, T, cam)
            # Stamped at 10 Hz: every mapper sees the same clock. Unstamped, each would read the wall
            # clock, and the people's voxels would decay at different frames in each (their 0.1 s
            # cadence), whatever the machine's speed makes of the sweep.
            stamp = 10**18 + i * 100_000_000
            grids = []
            for m in mappers:
                m.integrate(pts, conf, lab, T, stamp_ns=stamp, intrinsics=K)
                u = m.update_esdf()
                assert u is not None and u.grid3d is not None
                grids.append(u.grid3d)
            yield grids

    return run
