"""Codec: round trips for arbitrary valid messages, and one clear error for each kind of bad payload."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from foundation.strategies import messages
from hypothesis import given, settings
from pydantic import BaseModel

from riskfield.protocol import (
    DecodeError,
    EncodeError,
    EsdfGrid,
    Limits,
    PerceptionFrame,
    RobotState,
    VelocityCommand,
    decode,
    encode,
    to_map,
)


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    if isinstance(a, BaseModel):
        return type(a) is type(b) and all(_same(getattr(a, k), getattr(b, k)) for k in type(a).model_fields)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return a == b


@settings(max_examples=300, deadline=None)
@given(messages)
def test_round_trip(msg):
    back = decode(encode(msg), type(msg))
    assert _same(msg, back)
    assert decode(encode(back)).model_dump().keys() == msg.model_dump().keys()


def _frame(h=4, w=5) -> PerceptionFrame:
    return PerceptionFrame(T_WC=np.eye(4), points=np.zeros((h, w, 3), np.float32),
                           confidence=np.ones((h, w), np.float32), labels=np.zeros((h, w), np.uint16), keyframe_id=0)


def test_arrays_decode_without_copy():
    frame = _frame(64, 48)
    back = decode(encode(frame), PerceptionFrame)
    assert not back.points.flags.owndata and not back.points.flags.writeable
    assert back.points.dtype == np.dtype("<f4") and back.points.shape == (64, 48, 3)


def test_wire_layout_is_the_documented_one():
    m = to_map(_frame(2, 3))
    assert m["schema"] == "PerceptionFrame/1"
    assert set(m["header"]) == {"stamp_ns", "frame_id", "seq"}
    assert m["points"]["dtype"] == "<f4" and m["points"]["shape"] == [2, 3, 3]
    assert bytes(m["points"]["data"]) == np.zeros((2, 3, 3), np.float32).tobytes()
    assert m["labels"]["dtype"] == "<u2" and m["T_WC"]["dtype"] == "<f8"
    raw = msgpack.unpackb(encode(_frame(2, 3)))
    assert isinstance(raw["points"]["data"], bytes)


def _mutated(msg, **changes) -> bytes:
    m = to_map(msg)
    for path, value in changes.items():
        node = m
        *parents, leaf = path.split("__")
        for p in parents:
            node = node[p]
        if value is KeyError:
            del node[leaf]
        else:
            node[leaf] = value
    return msgpack.packb(m, use_bin_type=True)


CMD = VelocityCommand(linear=(0.5, 0, 0), angular=(0, 0, 0.1), source="test")


@pytest.mark.parametrize(
    ("payload", "field", "words"),
    [
        (b"\xc1\x00\x01", None, "not msgpack"),
        (encode(CMD)[:-3], None, "not msgpack"),
        (msgpack.packb([1, 2, 3]), None, "not a msgpack map"),
        (msgpack.packb({"linear": [0, 0, 0]}), None, "no 'schema'"),
        (_mutated(CMD, schema="Teleport/1"), None, "unknown schema"),
        (_mutated(CMD, schema="VelocityCommand/2"), None, "unknown schema"),
        (_mutated(CMD, linear=[float("nan"), 0, 0]), "linear[0]", "finite"),
        (_mutated(CMD, angular=[0, 0, float("inf")]), "angular[2]", "finite"),
        (_mutated(CMD, linear=[0, 0]), "linear[2]", "required"),
        (_mutated(CMD, source=KeyError), "source", "required"),
        (_mutated(CMD, header__seq=-1), "header.seq", ""),
        (_mutated(_frame(), points={"dtype": "<f8", "shape": [4, 5, 3], "data": b"\0" * 480}), "points", "dtype"),
        (_mutated(_frame(), points={"dtype": "<f4", "shape": [4, 5, 2], "data": b"\0" * 160}), "points", "shape"),
        (_mutated(_frame(), points={"dtype": "<f4", "shape": [4, 5, 3], "data": b"\0" * 10}), "points", "bytes"),
        (_mutated(_frame(), points={"dtype": "<f4", "shape": [2**40, 2**20, 3], "data": b""}), "points", "limit"),
        (_mutated(_frame(), points={"dtype": "<f4", "shape": [-1, 5, 3], "data": b""}), "points", "non-negative"),
        (_mutated(_frame(), points={"dtype": "<f4", "shape": [4, 5, 3]}), "points", "lacks"),
        (_mutated(_frame(), confidence={"dtype": "<f4", "shape": [4, 5],
                                        "data": np.full((4, 5), np.nan, np.float32).tobytes()}), "confidence", "NaN"),
        (_mutated(_frame(), labels={"dtype": "<u2", "shape": [3, 5], "data": b"\0" * 30}), None, "labels shape"),
        (_mutated(_frame(), T_WC="eye"), "T_WC", "ndarray"),
    ],
)
def test_bad_payloads_raise_one_clear_error(payload, field, words):
    with pytest.raises(DecodeError) as info:
        decode(payload)
    err = info.value
    if field is not None:
        assert err.field == field, str(err)
    assert words.lower() in str(err).lower()


def test_expected_schema_is_enforced():
    with pytest.raises(DecodeError, match="where 'RobotState/1' is expected"):
        decode(encode(CMD), RobotState)


def test_payload_and_array_limits_are_configurable():
    payload = encode(_frame(32, 32))
    with pytest.raises(DecodeError, match="over the limit"):
        decode(payload, limits=Limits(max_array_bytes=1000))
    with pytest.raises(DecodeError, match="payload of"):
        decode(payload, limits=Limits(max_payload_bytes=100))
    assert decode(payload, limits=Limits(max_array_bytes=32 * 32 * 12)).points.shape == (32, 32, 3)


def test_encode_refuses_non_finite_values():
    cmd = VelocityCommand(linear=(0, 0, 0), angular=(0, 0, 0), source="x")
    object.__setattr__(cmd, "linear", (float("nan"), 0.0, 0.0))
    with pytest.raises(EncodeError):
        encode(cmd)
    frame = _frame()
    frame.points[0, 0, 0] = np.inf
    with pytest.raises(EncodeError):
        encode(frame)


def test_python_construction_converts_compatible_dtypes_once():
    grid = EsdfGrid(origin=(0, 0, 0), voxel_size=0.1, distance=np.zeros((2, 2, 1)), risk_group=[[[0], [1]], [[0], [0]]],
                    groups=["high"], max_distance=1.0, unknown_is_occupied=False)
    assert grid.distance.dtype == np.float32 and grid.risk_group.dtype == np.uint8
    with pytest.raises(ValueError, match="cannot become"):
        EsdfGrid(origin=(0, 0, 0), voxel_size=0.1, distance=np.zeros((1, 1, 1), complex),
                 risk_group=np.zeros((1, 1, 1)),
                 groups=[], max_distance=1.0, unknown_is_occupied=False)
    with pytest.raises(ValueError, match="no entry in groups"):
        EsdfGrid(origin=(0, 0, 0), voxel_size=0.1, distance=np.zeros((1, 1, 1)), risk_group=np.full((1, 1, 1), 2),
                 groups=["high"], max_distance=1.0, unknown_is_occupied=False)


def test_non_unit_quaternion_is_rejected():
    with pytest.raises(ValueError, match="unit quaternion"):
        RobotState(position=(0, 0, 0), orientation=(0, 0, 0, 2), linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0))
    s = RobotState(position=(0, 0, 0), orientation=(0, 0, math.sin(0.4), math.cos(0.4)),
                   linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0))
    assert s.yaw == pytest.approx(0.8)


def test_unknown_extra_fields_are_ignored():
    m = to_map(CMD)
    m["future_field"] = {"anything": [1, 2]}
    assert decode(msgpack.packb(m, use_bin_type=True)) == CMD
