"""Serial framing of the AgileX LIMO chassis (pure: bytes in, bytes or dataclasses out).

Every frame is 14 bytes::

    0x55 0x0E id_hi id_lo d0 d1 d2 d3 d4 d5 d6 d7 count checksum

``checksum = (d0 + … + d7) & 0xFF`` (data bytes only) and ``count`` is 0. Multi-byte fields
are big-endian and signed unless noted. Commands go from the computer to the chassis
(``0x111`` motion, ``0x421`` control mode), feedback the other way (``0x211`` system state,
``0x221`` motion state, ``0x311`` wheel odometry, ``0x321``/``0x322``/``0x323`` IMU).

Each message is a frozen dataclass with ``ID``, ``from_data(data)`` and ``to_data()``, so the
bridge and the chassis emulator share one definition of every field, its scale and its sign.
``FrameParser`` turns an arbitrary byte stream into frames: it resynchronises on the header
after garbage and rejects frames whose checksum is wrong, counting both.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import ClassVar

HEADER = b"\x55\x0e"
FRAME_LEN = 14
DATA_LEN = 8

MOTION_COMMAND_ID = 0x111
CONTROL_MODE_ID = 0x421
SYSTEM_STATE_ID = 0x211
MOTION_STATE_ID = 0x221
ODOMETRY_ID = 0x311
IMU_ACCEL_ID = 0x321
IMU_GYRO_ID = 0x322
IMU_EULER_ID = 0x323

_I16_MIN, _I16_MAX = -(2**15), 2**15 - 1


def checksum(data: bytes) -> int:
    return sum(data) & 0xFF


def encode_frame(frame_id: int, data: bytes) -> bytes:
    """One 14-byte frame; ``data`` must be exactly 8 bytes."""
    if len(data) != DATA_LEN:
        raise ValueError(f"a LIMO frame carries {DATA_LEN} data bytes, got {len(data)}")
    if not 0 <= frame_id <= 0xFFFF:
        raise ValueError(f"frame id {frame_id:#x} does not fit in 16 bits")
    return HEADER + frame_id.to_bytes(2, "big") + data + bytes((0, checksum(data)))


def _i16(value: float) -> int:
    """Round and saturate to int16: a scaled value outside the wire range must not wrap sign."""
    if not math.isfinite(value):
        raise ValueError(f"{value} cannot be sent to the chassis")
    return max(_I16_MIN, min(_I16_MAX, round(value)))


@dataclass(frozen=True)
class Frame:
    """A frame whose header and checksum were valid; ``data`` is the 8 data bytes."""

    id: int
    data: bytes


# -- commands (computer → chassis) -----------------------------------------------------------


@dataclass(frozen=True)
class MotionCommand:
    """``0x111``: linear (m/s), angular (rad/s), lateral (m/s, mecanum), steering (Ackermann).

    ``steering`` is the chassis's steering field, not an angle of the robot: AgileX sends the
    inner front wheel's angle divided by 1.64 (``ackermann.steering_field``).
    On the wire: int16 mm/s, 0.001 rad/s, mm/s, 0.001 (field), saturated (never wrapped)."""

    ID: ClassVar[int] = MOTION_COMMAND_ID
    linear: float = 0.0
    angular: float = 0.0
    lateral: float = 0.0
    steering: float = 0.0

    def to_data(self) -> bytes:
        return struct.pack(
            ">hhhh", _i16(self.linear * 1e3), _i16(self.angular * 1e3), _i16(self.lateral * 1e3),
            _i16(self.steering * 1e3),
        )

    @classmethod
    def from_data(cls, data: bytes) -> MotionCommand:
        lin, ang, lat, steer = struct.unpack(">hhhh", data)
        return cls(lin / 1e3, ang / 1e3, lat / 1e3, steer / 1e3)

    @property
    def is_stop(self) -> bool:
        return self.linear == 0.0 and self.angular == 0.0 and self.lateral == 0.0


@dataclass(frozen=True)
class ControlModeCommand:
    """``0x421``: d0 = 1 puts the chassis in serial command mode (0 hands control back);
    d2 = 1 also switches it to mecanum motion, ``{1, 0, 1, 0, 0, 0, 0, 0}`` (agilexrobotics/limo_ros
    ``limo_base/src/limo_driver.cpp``, ``LimoDriver::enableMcMode``; ``enableCommandedMode`` sends d2 = 0)."""

    ID: ClassVar[int] = CONTROL_MODE_ID
    enable: bool = True
    mecanum: bool = False

    def to_data(self) -> bytes:
        return bytes((1 if self.enable else 0, 0, 1 if self.mecanum else 0, 0, 0, 0, 0, 0))

    @classmethod
    def from_data(cls, data: bytes) -> ControlModeCommand:
        return cls(enable=data[0] == 1, mecanum=data[2] == 1)


# -- feedback (chassis → computer) -----------------------------------------------------------


@dataclass(frozen=True)
class SystemState:
    """``0x211``: vehicle state, control mode (1 = serial command mode), battery (V),
    error bits (uint16), motion mode (0 differential, 1 Ackermann, 2 mecanum)."""

    ID: ClassVar[int] = SYSTEM_STATE_ID
    vehicle_state: int = 0
    control_mode: int = 0
    battery_v: float = 0.0
    error_bits: int = 0
    motion_mode: int = 0

    def to_data(self) -> bytes:
        battery = max(0, min(0xFFFF, round(self.battery_v * 10)))
        return struct.pack(">BBHHBx", self.vehicle_state, self.control_mode, battery, self.error_bits,
                           self.motion_mode)

    @classmethod
    def from_data(cls, data: bytes) -> SystemState:
        vs, cm, battery, errors, mm = struct.unpack(">BBHHBx", data)
        return cls(vs, cm, battery / 10.0, errors, mm)


@dataclass(frozen=True)
class MotionState:
    """``0x221``: measured linear (m/s), angular (rad/s), lateral (m/s), steering field (Ackermann:
    ×2.47 when positive, ×1.64 otherwise is the inner wheel's angle, ``ackermann.inner_from_feedback_field``)."""

    ID: ClassVar[int] = MOTION_STATE_ID
    linear: float = 0.0
    angular: float = 0.0
    lateral: float = 0.0
    steering: float = 0.0

    def to_data(self) -> bytes:
        return MotionCommand(self.linear, self.angular, self.lateral, self.steering).to_data()

    @classmethod
    def from_data(cls, data: bytes) -> MotionState:
        c = MotionCommand.from_data(data)
        return cls(c.linear, c.angular, c.lateral, c.steering)


@dataclass(frozen=True)
class Odometry:
    """``0x311``: cumulative left and right wheel travel (m; int32 mm on the wire)."""

    ID: ClassVar[int] = ODOMETRY_ID
    left: float = 0.0
    right: float = 0.0

    @property
    def left_mm(self) -> int:
        return round(self.left * 1e3)

    @property
    def right_mm(self) -> int:
        return round(self.right * 1e3)

    def to_data(self) -> bytes:
        # The chassis counters are int32 and wrap; emulate that rather than raising.
        wrap = lambda mm: (mm + 2**31) % 2**32 - 2**31  # noqa: E731
        return struct.pack(">ii", wrap(self.left_mm), wrap(self.right_mm))

    @classmethod
    def from_data(cls, data: bytes) -> Odometry:
        left, right = struct.unpack(">ii", data)
        return cls(left / 1e3, right / 1e3)


@dataclass(frozen=True)
class ImuAccel:
    """``0x321``: linear acceleration x, y, z (m/s²; int16 ×100 on the wire)."""

    ID: ClassVar[int] = IMU_ACCEL_ID
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def to_data(self) -> bytes:
        return struct.pack(">hhhxx", _i16(self.x * 100), _i16(self.y * 100), _i16(self.z * 100))

    @classmethod
    def from_data(cls, data: bytes) -> ImuAccel:
        x, y, z = struct.unpack(">hhhxx", data)
        return cls(x / 100, y / 100, z / 100)


@dataclass(frozen=True)
class ImuGyro:
    """``0x322``: angular rate about x, y, z (rad/s; int16 0.01 deg/s on the wire, signed)."""

    ID: ClassVar[int] = IMU_GYRO_ID
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def to_data(self) -> bytes:
        d = lambda r: _i16(math.degrees(r) * 100)  # noqa: E731
        return struct.pack(">hhhxx", d(self.x), d(self.y), d(self.z))

    @classmethod
    def from_data(cls, data: bytes) -> ImuGyro:
        x, y, z = struct.unpack(">hhhxx", data)
        return cls(math.radians(x / 100), math.radians(y / 100), math.radians(z / 100))


@dataclass(frozen=True)
class ImuEuler:
    """``0x323``: yaw, pitch, roll (rad; int16 0.01 deg on the wire, signed)."""

    ID: ClassVar[int] = IMU_EULER_ID
    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0

    def to_data(self) -> bytes:
        d = lambda r: _i16(math.degrees(r) * 100)  # noqa: E731
        return struct.pack(">hhhxx", d(self.yaw), d(self.pitch), d(self.roll))

    @classmethod
    def from_data(cls, data: bytes) -> ImuEuler:
        yaw, pitch, roll = struct.unpack(">hhhxx", data)
        return cls(math.radians(yaw / 100), math.radians(pitch / 100), math.radians(roll / 100))


Command = MotionCommand | ControlModeCommand
Feedback = SystemState | MotionState | Odometry | ImuAccel | ImuGyro | ImuEuler

MESSAGES: dict[int, type] = {
    cls.ID: cls
    for cls in (MotionCommand, ControlModeCommand, SystemState, MotionState, Odometry, ImuAccel, ImuGyro, ImuEuler)
}


def encode(msg: Command | Feedback) -> bytes:
    """The 14-byte frame of a command or feedback message."""
    return encode_frame(msg.ID, msg.to_data())


def decode(frame: Frame) -> Command | Feedback | None:
    """The message a valid frame carries; ``None`` for an id this module does not know."""
    cls = MESSAGES.get(frame.id)
    return None if cls is None else cls.from_data(frame.data)


class FrameParser:
    """Streaming parser: ``feed(bytes)`` returns every complete, valid frame seen so far.

    The stream may start mid-frame, lose bytes or carry noise. The parser looks for the
    two-byte header, takes 14 bytes, and checks the checksum; on a bad checksum it drops only
    the first header byte and searches again, because a real frame may start inside the
    rejected bytes. The count byte is not checked (the chassis may use it as a rolling counter).
    Counters: ``frames_ok``, ``frames_bad`` (checksum wrong),
    ``bytes_skipped`` (bytes outside any valid frame).
    """

    def __init__(self, max_buffer: int = 4096):
        self._buf = bytearray()
        self._max = max_buffer
        self.frames_ok = 0
        self.frames_bad = 0
        self.bytes_skipped = 0

    def reset(self) -> None:
        """Forget a partial frame (after a reconnect the rest of it will never arrive)."""
        self.bytes_skipped += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes) -> list[Frame]:
        buf = self._buf
        buf += data
        out: list[Frame] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                # Keep a trailing 0x55: it may be the first half of the next header.
                keep = 1 if buf[-1:] == HEADER[:1] else 0
                self.bytes_skipped += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.bytes_skipped += start
                del buf[:start]
            if len(buf) < FRAME_LEN:
                break
            data8 = bytes(buf[4:12])
            if buf[13] == checksum(data8):
                out.append(Frame((buf[2] << 8) | buf[3], data8))
                self.frames_ok += 1
                del buf[:FRAME_LEN]
            else:
                self.frames_bad += 1
                self.bytes_skipped += 1
                del buf[:1]
        if len(buf) > self._max:  # cannot happen with the logic above; a guard against a bug flooding memory
            self.bytes_skipped += len(buf)
            buf.clear()
        return out
