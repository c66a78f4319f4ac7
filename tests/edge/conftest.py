"""Shared inputs for the edge tests."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from riskfield.protocol import VelocityCommand, encode


@pytest.fixture
def bad_velocity_payloads() -> list[bytes]:
    """Payloads a ``cmd/safe`` subscriber must reject without stopping: random bytes, empty,
    truncated msgpack, wrong schema, NaN/Inf, wrong types and dtypes, a giant declared shape,
    a huge list, not a map."""
    rng = np.random.default_rng(7)
    good = msgpack.unpackb(encode(VelocityCommand(linear=(0.2, 0.0, 0.0), angular=(0.0, 0.0, 0.1), source="fuzz")))
    return [
        rng.bytes(40),
        b"",
        b"\xc1",
        encode(VelocityCommand.zero("fuzz"))[:-3],
        msgpack.packb({**good, "schema": "RobotState/1"}),
        msgpack.packb({**good, "schema": "VelocityCommand/9"}),
        msgpack.packb({**good, "linear": [float("nan"), 0.0, 0.0]}),
        msgpack.packb({**good, "angular": [0.0, 0.0, float("inf")]}),
        msgpack.packb({**good, "linear": ["a", 0, 0]}),
        msgpack.packb({**good, "linear": {"dtype": "<f8", "shape": [10**9], "data": b""}}),
        msgpack.packb({**good, "angular": [0.0] * 100_000}),
        msgpack.packb({k: v for k, v in good.items() if k != "source"}),
        msgpack.packb([1, 2, 3]),
    ]
