"""The serial port of the chassis: non-blocking reads and writes, and reopening after loss.

A USB adapter that is unplugged, a UART whose device node disappears, or a pseudo-terminal
whose other end closes all look the same from here: a read or write raises. The link then
closes the port and tries to open the path again every ``reconnect_s``; the path may be a
symlink that meanwhile points to a new device.
"""

from __future__ import annotations

import math

import serial


class SerialLink:
    def __init__(self, port: str, baudrate: int = 460800, reconnect_s: float = 0.5):
        self.port = port
        self.baudrate = baudrate
        self.reconnect_s = reconnect_s
        self.last_error = ""
        self.write_drops = 0  # bytes the OS would not take (full buffer): the frame is lost, not queued
        self._serial: serial.Serial | None = None
        self._next_try = -math.inf

    @property
    def is_open(self) -> bool:
        return self._serial is not None

    def try_open(self, now: float) -> bool:
        """Open the port if it is closed and a retry is due; True when it just opened."""
        if self._serial is not None or now < self._next_try:
            return False
        self._next_try = now + self.reconnect_s
        try:
            # timeout=0 / write_timeout=0: never block the node's loop on the line.
            self._serial = serial.Serial(self.port, self.baudrate, timeout=0, write_timeout=0, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            self.last_error = f"cannot open {self.port}: {exc}"
            return False
        self._serial.reset_input_buffer()
        return True

    def fileno(self) -> int:
        """The open port's file descriptor (-1 when closed), for a writer on another thread."""
        return self._serial.fileno() if self._serial is not None else -1

    def read(self) -> bytes:
        """Whatever bytes are waiting (maybe none). Raises ``ConnectionError`` once when the port is lost."""
        if self._serial is None:
            return b""
        try:
            return self._serial.read(4096)
        except (serial.SerialException, OSError) as exc:
            self._lost(f"read from {self.port} failed: {exc}")
            raise ConnectionError(self.last_error) from None

    def write(self, data: bytes) -> None:
        """Write without blocking. Raises ``ConnectionError`` when the port is lost."""
        if self._serial is None or not data:
            return
        try:
            n = self._serial.write(data)
        except serial.SerialTimeoutException:
            n = 0
        except (serial.SerialException, OSError) as exc:
            self._lost(f"write to {self.port} failed: {exc}")
            raise ConnectionError(self.last_error) from None
        if n is not None and n < len(data):
            self.write_drops += len(data) - n

    def _lost(self, why: str) -> None:
        self.last_error = why
        self.close()

    def close(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            except (serial.SerialException, OSError):
                pass
            self._serial = None
