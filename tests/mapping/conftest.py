"""Shared scenes for the mapping tests: analytic primitives rendered as pointmaps."""

from __future__ import annotations

import pytest

from riskfield.protocol import ade20k
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Plane

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
