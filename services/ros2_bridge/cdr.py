"""A minimal XCDR1 (plain CDR, little-endian) writer and reader for ROS 2 messages.

zenoh-bridge-ros2dds forwards DDS samples as their raw CDR bytes: a 4-byte encapsulation
header (``00 01 00 00`` = CDR little-endian) followed by the body, in which every primitive
is aligned to its own size *relative to the start of the body*. Strings are a uint32 length
that counts the terminating NUL, the bytes, then the NUL. Fixed arrays have no length prefix.
"""

from __future__ import annotations

import struct

CDR_LE = b"\x00\x01\x00\x00"


class CdrWriter:
    def __init__(self) -> None:
        self._buf = bytearray()

    def _align(self, n: int) -> None:
        self._buf += b"\x00" * (-len(self._buf) % n)

    def _put(self, fmt: str, *values: float | int) -> None:
        size = struct.calcsize("<" + fmt[0])
        self._align(size)
        self._buf += struct.pack("<" + fmt, *values)

    def int32(self, v: int) -> None:
        self._put("i", v)

    def uint32(self, v: int) -> None:
        self._put("I", v)

    def float64(self, *v: float) -> None:
        self._put("d" * len(v), *v)

    def string(self, s: str) -> None:
        data = s.encode() + b"\x00"
        self.uint32(len(data))
        self._buf += data

    def bytes(self) -> bytes:
        return CDR_LE + bytes(self._buf)


class CdrReader:
    def __init__(self, data: bytes):
        if len(data) < 4 or data[:2] != b"\x00\x01":
            raise ValueError("not little-endian plain CDR (encapsulation header must start 00 01)")
        self._body = memoryview(data)[4:]
        self._pos = 0

    def _get(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt[0])
        self._pos += -self._pos % size
        n = struct.calcsize("<" + fmt)
        if self._pos + n > len(self._body):
            raise ValueError("CDR data ends early")
        out = struct.unpack_from("<" + fmt, self._body, self._pos)
        self._pos += n
        return out

    def int32(self) -> int:
        return self._get("i")[0]

    def uint32(self) -> int:
        return self._get("I")[0]

    def float64(self, n: int = 1) -> tuple[float, ...]:
        return self._get("d" * n)

    def string(self) -> str:
        n = self.uint32()
        if n == 0 or self._pos + n > len(self._body):
            raise ValueError("bad CDR string length")
        raw = bytes(self._body[self._pos:self._pos + n - 1])
        self._pos += n
        return raw.decode(errors="replace")
