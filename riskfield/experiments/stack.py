"""The full service stack as processes over a loopback Zenoh router, for the hardware-style
benchmarks (teleop, navigation) and their tests.

``Stack`` starts the router in this process and each service in its own interpreter through the
runtime's process runner (``services/runtime/processes.py``: spawn model, never a fork of a
process holding a session; a service counts as started once its liveliness token is visible).
``Recorder`` keeps every message of a few keys with its arrival time, decoded.

Perception: ``gt`` relays the simulator's ground-truth frames (``sim/truth``) to
``perception/frame``; ``sim`` runs the perception service's FM-like ``sim`` backend on the
simulator's images.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from riskfield.protocol import ENCODING, Keys, Message, decode, encode
from riskfield.services.runtime.processes import Child, EmbeddedRouter, ProcessRunner, client_session

#: The safety filter as the benchmarks run it (50 Hz control).
FAST_FILTER = ["--set", "rate_hz=50"]


def perception_args(mode: str) -> tuple[str, list[str]]:
    """The service and its arguments that turn simulator output into ``perception/frame``."""
    if mode == "gt":
        return "relay", ["--set", "in_key=sim/truth", "--set", "out_key=perception/frame",
                         "--set", "schema_name=PerceptionFrame/1", "--set", "queue=latest"]
    if mode == "sim":
        return "perception", ["--set", "geometry=sim", "--set", "labels=sim"]
    raise ValueError(f"perception mode {mode!r}: use gt or sim")


@dataclass
class Stack:
    """Router + services for one robot id. Use as a context manager; ``start`` more later."""

    robot: str
    router: EmbeddedRouter = field(default_factory=EmbeddedRouter)
    procs: dict[str, Child] = field(default_factory=dict)
    _stack: contextlib.ExitStack = field(default_factory=contextlib.ExitStack)

    def __enter__(self) -> Stack:
        self._stack.__enter__()
        self._stack.enter_context(self.router)
        self.session = self._stack.enter_context(client_session(self.router.endpoint))
        self.runner = ProcessRunner(self.router.endpoint, Keys(robot=self.robot))
        return self

    def __exit__(self, *exc: object) -> None:
        for name in list(self.procs)[::-1]:
            self.stop(name)
        self.runner.close()
        self._stack.__exit__(*exc)

    def start(self, label: str, service: str, args: Sequence[str] = (), wait: bool = True,
              timeout_s: float = 60.0) -> Child:
        """Start ``service`` as ``label``; with ``wait``, return once it is alive (raise if not)."""
        self.procs[label] = self.runner.spawn(label, service, ["--robot", self.robot, *args],
                                              session=self.session if wait else None, timeout_s=timeout_s)
        return self.procs[label]

    def stop(self, label: str) -> int | None:
        """Stop one service; its exit code."""
        if self.procs.pop(label, None) is None:
            return None
        return self.runner.stop(label)

    @property
    def keys(self) -> Keys:
        """The keys of this stack's robot."""
        return self.runner.keys


def publish(session: Any, key: str, msg: Message | bytes) -> None:
    """Put a message (or an encoded payload) that must arrive whole: congestion control BLOCK
    (the default, DROP, sheds load under CPU pressure, and a lost goal stalls an experiment)."""
    payload = msg if isinstance(msg, (bytes, bytearray)) else encode(msg)
    session.put(key, bytes(payload), encoding=zenoh.Encoding(ENCODING),
                congestion_control=zenoh.CongestionControl.BLOCK)


class Recorder:
    """Every message on some keys, decoded, with its arrival time (``time.monotonic``)."""

    def __init__(self, session: Any, keys: dict[str, tuple[str, type[Message]]]):
        self.items: dict[str, list[tuple[float, Any]]] = {name: [] for name in keys}
        self._lock = threading.Lock()
        self._subs = []
        for name, (key, msg_type) in keys.items():
            def on_sample(sample: Any, name: str = name, msg_type: type[Message] = msg_type) -> None:
                try:
                    msg = decode(sample.payload.to_bytes(), msg_type)
                except Exception:
                    return
                with self._lock:
                    self.items[name].append((time.monotonic(), msg))

            self._subs.append(session.declare_subscriber(key, on_sample))

    def snapshot(self, name: str) -> list[tuple[float, Any]]:
        with self._lock:
            return list(self.items[name])

    def clear(self) -> None:
        with self._lock:
            for v in self.items.values():
                v.clear()

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


@contextlib.contextmanager
def recording(session: Any, keys: dict[str, tuple[str, type[Message]]]) -> Iterator[Recorder]:
    rec = Recorder(session, keys)
    try:
        yield rec
    finally:
        rec.close()
