"""A command watchdog on its own thread: a stop frame reaches the chassis even while the node's loop is stuck.

The bridge core's watchdog (``bridge.LimoBridge.tick``) runs on the node's loop, so a handler
that blocks (a slow publish, a stuck session, a bug) would also block the stop. No AgileX
source states a command timeout of the chassis itself (limo_ros ``limo_driver.cpp``, limo_ros2
and pylimo 0.3.5 send commands only when one comes and never mention one), so nothing below the
bridge is known to stop a chassis whose last frame said "move".

``CommandWatchdog`` writes to a duplicate of the serial port's file descriptor (``os.dup``), not
through the loop's ``serial.Serial``: a 14-byte ``write`` on a tty is one atomic chunk, so its
frames cannot interleave with the loop's. Its lock guards only that descriptor (attach, detach,
write); the loop takes it for the instant of a port open or close, never while it handles a
message, so a loop stuck anywhere else cannot hold it. The loop tells it about commands with
plain attribute writes (``commanded``, ``settled``), which need no lock.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time

from .protocol import MotionCommand, encode

_STOP = encode(MotionCommand())


class CommandWatchdog:
    """Writes a stop frame once the last moving command is older than ``timeout_s``, and repeats it
    every ``repeat_s`` until the loop itself writes a stop (``settled``) or a new command comes.

    ``check_s`` is the thread's period: a stop goes out at most ``timeout_s + check_s`` after the
    last moving command. ``fired`` counts the times it stopped a moving chassis, ``frames`` every
    stop frame it wrote, ``write_errors`` the writes the port refused (lost device, full buffer).
    """

    def __init__(self, timeout_s: float, repeat_s: float, check_s: float | None = None):
        self.timeout_s = timeout_s
        self.repeat_s = repeat_s
        self.check_s = check_s if check_s is not None else min(0.01, timeout_s / 10)
        self.fired = 0
        self.frames = 0
        self.write_errors = 0
        self._moving = False
        self._last_cmd = 0.0
        self._last_stop = 0.0
        self._fd = -1
        self._fd_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- from the loop (no lock but the descriptor's) ---------------------------------------------
    def attach(self, fd: int) -> None:
        """Write to a duplicate of ``fd`` from now on (the port just opened)."""
        dup = os.dup(fd)
        with self._fd_lock:
            old, self._fd = self._fd, dup
        if old >= 0:
            with contextlib.suppress(OSError):
                os.close(old)

    def detach(self) -> None:
        """The port is gone: stop writing (and close the duplicate)."""
        with self._fd_lock:
            old, self._fd = self._fd, -1
            if old >= 0:
                with contextlib.suppress(OSError):
                    os.close(old)

    def commanded(self, moving: bool, now: float) -> None:
        """The loop is about to write a motion frame; ``moving`` is False for a stop frame.
        The time is written before the flag, so the thread never sees a fresh flag with an old time."""
        self._last_cmd = now
        self._moving = moving

    def settled(self) -> None:
        """The loop wrote a stop of its own (its watchdog, shutdown): nothing left to cover."""
        self._moving = False

    # -- thread ------------------------------------------------------------------------------------
    def start(self) -> CommandWatchdog:
        self._thread = threading.Thread(target=self._run, name="limo-watchdog", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        self.detach()

    def check(self, now: float) -> bool:
        """One round of the thread's duty at ``now``; True when it wrote a stop frame."""
        if not self._moving or now - self._last_cmd <= self.timeout_s:
            return False
        first = self._last_stop < self._last_cmd
        if not first and now - self._last_stop < self.repeat_s:
            return False
        with self._fd_lock:
            # Re-read under the lock: a command the loop wrote meanwhile must not be cut off.
            if self._fd < 0 or not self._moving or now - self._last_cmd <= self.timeout_s:
                return False
            try:
                n = os.write(self._fd, _STOP)
            except OSError:
                n = 0
        if n != len(_STOP):
            self.write_errors += 1
            return False
        self._last_stop = now
        self.frames += 1
        self.fired += int(first)
        return True

    def _run(self) -> None:
        while not self._stop.wait(self.check_s):
            self.check(time.monotonic())
