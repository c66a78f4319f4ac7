"""The client side of a stack, for programs that drive one from outside (tests, benchmarks, the
demo): put a message so that it arrives, and keep what arrives on a key.

One home for both: the test API module re-exports them as test API, and
``riskfield.experiments.stack`` records several keys with ``Collector``s.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import zenoh

from riskfield.protocol import ENCODING, DecodeError, Message, decode, encode

from .processes import wait_until


def put(session: zenoh.Session, key: str, msg: Message | bytes) -> None:
    """Put a message (or an encoded payload) that must arrive whole: congestion control BLOCK
    (the default, DROP, sheds load under CPU pressure: a test's burst or a benchmark's goal would
    be lost)."""
    payload = msg if isinstance(msg, (bytes, bytearray)) else encode(msg)
    session.put(key, bytes(payload), encoding=zenoh.Encoding(ENCODING),
                congestion_control=zenoh.CongestionControl.BLOCK)


class Collector:
    """Subscribes to a key and keeps every decoded message (or raw payload) it sees, with its key
    and arrival time (``time.monotonic``). A sample that does not decode as ``msg_type`` is
    counted in ``undecodable``, not kept."""

    def __init__(self, session: zenoh.Session, key: str, msg_type: type[Message] | None = None):
        self.items: list[Any] = []
        self.keys: list[str] = []
        self.times: list[float] = []
        self.undecodable = 0
        self._lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            raw = sample.payload.to_bytes()
            try:
                item = decode(raw, msg_type) if msg_type is not None else raw
            except DecodeError:
                with self._lock:
                    self.undecodable += 1
                return
            with self._lock:
                self.items.append(item)
                self.keys.append(str(sample.key_expr))
                self.times.append(time.monotonic())

        self._sub = session.declare_subscriber(key, on_sample)

    def wait(self, n: int = 1, timeout_s: float = 10.0) -> list[Any]:
        if not wait_until(lambda: len(self.items) >= n, timeout_s):
            raise TimeoutError(f"got {len(self.items)} of {n} messages in {timeout_s} s")
        with self._lock:
            return list(self.items)

    def snapshot(self) -> list[tuple[float, Any]]:
        """(arrival time, item) of everything kept so far."""
        with self._lock:
            return list(zip(self.times, self.items, strict=True))

    def clear(self) -> None:
        with self._lock:
            self.items.clear()
            self.keys.clear()
            self.times.clear()

    def close(self) -> None:
        self._sub.undeclare()
