"""LIMO serial framing: encoding, field scales and signs, and the resynchronising parser."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.edge.limo import protocol as p

i16 = st.integers(-(2**15), 2**15 - 1)


def test_frame_layout_matches_the_reference() -> None:
    frame = p.encode(p.MotionCommand(linear=0.5, angular=-0.25, lateral=0.0, steering=0.1))
    assert len(frame) == 14
    assert frame[:4] == bytes((0x55, 0x0E, 0x01, 0x11))
    assert frame[4:6] == (500).to_bytes(2, "big", signed=True)
    assert frame[6:8] == (-250).to_bytes(2, "big", signed=True)
    assert frame[10:12] == (100).to_bytes(2, "big", signed=True)
    assert frame[12] == 0
    assert frame[13] == sum(frame[4:12]) & 0xFF


def test_control_mode_enable_frame() -> None:
    frame = p.encode(p.ControlModeCommand(enable=True))
    assert frame[2:4] == b"\x04\x21" and frame[4] == 1 and frame[13] == 1


def test_wire_values_saturate_instead_of_wrapping() -> None:
    frame = p.encode(p.MotionCommand(linear=100.0, angular=-100.0))
    back = p.MotionCommand.from_data(frame[4:12])
    assert back.linear == pytest.approx(32.767) and back.angular == pytest.approx(-32.768)


def test_non_finite_values_are_refused() -> None:
    with pytest.raises(ValueError):
        p.encode(p.MotionCommand(linear=math.nan))


@given(i16, i16, i16, i16)
def test_motion_round_trip_is_exact_in_wire_units(a: int, b: int, c: int, d: int) -> None:
    msg = p.MotionCommand(a / 1e3, b / 1e3, c / 1e3, d / 1e3)
    (frame,) = p.FrameParser().feed(p.encode(msg))
    assert p.decode(frame) == msg


@given(st.integers(-(2**31), 2**31 - 1), st.integers(-(2**31), 2**31 - 1))
def test_odometry_is_signed_int32_mm(left: int, right: int) -> None:
    data = left.to_bytes(4, "big", signed=True) + right.to_bytes(4, "big", signed=True)
    odo = p.Odometry.from_data(data)
    assert odo.left_mm == left and odo.right_mm == right
    assert odo.to_data() == data


def test_imu_values_are_signed_and_scaled() -> None:
    data = (-9000).to_bytes(2, "big", signed=True) + (1500).to_bytes(2, "big", signed=True) + bytes(4)
    euler = p.ImuEuler.from_data(data)
    assert euler.yaw == pytest.approx(math.radians(-90.0))
    assert euler.pitch == pytest.approx(math.radians(15.0))
    gyro = p.ImuGyro.from_data((-1000).to_bytes(2, "big", signed=True) * 3 + bytes(2))
    assert gyro.z == pytest.approx(math.radians(-10.0))
    accel = p.ImuAccel.from_data((-981).to_bytes(2, "big", signed=True) * 3 + bytes(2))
    assert accel.z == pytest.approx(-9.81)


def test_system_state_fields() -> None:
    data = bytes((2, 1)) + (123).to_bytes(2, "big") + (0x8001).to_bytes(2, "big") + bytes((1, 0))
    s = p.SystemState.from_data(data)
    assert (s.vehicle_state, s.control_mode, s.error_bits, s.motion_mode) == (2, 1, 0x8001, 1)
    assert s.battery_v == pytest.approx(12.3)
    assert s.to_data() == data


def test_parser_resyncs_after_garbage_and_split_reads() -> None:
    frames = [p.encode(p.Odometry(i * 0.01, -i * 0.02)) for i in range(5)]
    stream = b"\x00\x55\xff" + frames[0] + b"\x55" + frames[1] + b"\x55\x0e\x01" + frames[2] + frames[3] + frames[4]
    parser = p.FrameParser()
    got = []
    for i in range(0, len(stream), 5):  # arbitrary read boundaries
        got += parser.feed(stream[i:i + 5])
    assert [p.decode(f) for f in got] == [p.Odometry(i * 0.01, -i * 0.02) for i in range(5)]
    assert parser.frames_ok == 5
    assert parser.bytes_skipped > 0


def test_parser_rejects_a_bad_checksum_and_keeps_the_next_frame() -> None:
    bad = bytearray(p.encode(p.MotionState(0.3, 0.1)))
    bad[13] ^= 0x01
    good = p.encode(p.MotionState(0.2, 0.0))
    parser = p.FrameParser()
    got = parser.feed(bytes(bad) + good)
    assert [p.decode(f) for f in got] == [p.MotionState(0.2, 0.0)]
    assert parser.frames_bad == 1


def test_parser_finds_a_frame_that_starts_inside_a_rejected_one() -> None:
    good = p.encode(p.Odometry(1.0, 2.0))
    # A false header followed by the first bytes of a real frame: the real one must survive.
    stream = b"\x55\x0e\x02\x11" + good
    got = p.FrameParser().feed(stream)
    assert [p.decode(f) for f in got] == [p.Odometry(1.0, 2.0)]


@settings(max_examples=200)
@given(st.binary(max_size=200), st.lists(st.tuples(i16, i16), min_size=1, max_size=5), st.binary(max_size=50))
def test_parser_never_crashes_and_finds_frames_after_noise(noise: bytes, values: list, tail: bytes) -> None:
    msgs = [p.MotionState(a / 1e3, b / 1e3) for a, b in values]
    parser = p.FrameParser()
    parser.feed(noise)
    parser.reset()  # what the bridge does after a reconnect: a partial frame from the noise is gone
    got = parser.feed(b"".join(p.encode(m) for m in msgs))
    assert [p.decode(f) for f in got] == msgs
    parser.feed(tail)  # trailing noise is tolerated
    assert len(parser._buf) < p.FRAME_LEN


def test_unknown_ids_decode_to_none() -> None:
    (frame,) = p.FrameParser().feed(p.encode_frame(0x999, bytes(8)))
    assert p.decode(frame) is None
    with pytest.raises(ValueError):
        p.encode_frame(0x111, bytes(7))
