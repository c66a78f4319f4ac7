"""Wake the node's loop thread when an input descriptor becomes readable.

The runtime's loop wakes on Zenoh samples and timers, not on file descriptors. Polling an
input device every millisecond costs latency (half a period on average) and CPU; instead a
helper thread waits in ``select`` on the device and calls ``wake()`` (the node turns that
into a session-local Zenoh put on a key it subscribes to, which the loop serves at once).
The thread never reads the device itself: the loop thread does, so the gateway core stays
single-threaded. After a wake the thread waits until the loop reports ``drained()`` (or
``max_wait_s``) so one burst of events is one wake, not a storm.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
from collections.abc import Callable


class FdWaker:
    def __init__(self, wake: Callable[[], None], max_wait_s: float = 0.05):
        self._wake = wake
        self._max_wait = max_wait_s
        self._fd = -1
        self._drained = threading.Event()
        self._stop = threading.Event()
        self._pipe_r, self._pipe_w = os.pipe()  # interrupts select when the fd changes or on stop
        self.wakes = 0
        self._thread = threading.Thread(target=self._run, name="fd-waker", daemon=True)
        self._thread.start()

    def watch(self, fd: int) -> None:
        """Wait on ``fd`` from now on (−1: on nothing)."""
        if fd != self._fd:
            self._fd = fd
            with contextlib.suppress(OSError):
                os.write(self._pipe_w, b"x")

    def drained(self) -> None:
        self._drained.set()

    def _run(self) -> None:
        while not self._stop.is_set():
            fd = self._fd
            fds = [self._pipe_r] + ([fd] if fd >= 0 else [])
            try:
                ready, _, _ = select.select(fds, [], [], 1.0)
            except (OSError, ValueError):  # closed under us by the loop thread (device lost)
                self._stop.wait(0.01)
                continue
            if self._pipe_r in ready:
                with contextlib.suppress(OSError):
                    os.read(self._pipe_r, 64)
                continue
            if fd in ready and fd == self._fd:
                self._drained.clear()
                self.wakes += 1
                try:
                    self._wake()
                except Exception:  # the session is closing: nothing left to wake
                    self._stop.wait(0.1)
                self._drained.wait(self._max_wait)

    def close(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            os.write(self._pipe_w, b"x")
        self._thread.join(2.0)
        for fd in (self._pipe_r, self._pipe_w):
            with contextlib.suppress(OSError):
                os.close(fd)
