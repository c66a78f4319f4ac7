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
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from riskfield.protocol import Keys, Message
from riskfield.services.runtime.client import Collector, put
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


#: Put a message that must arrive whole (a lost goal stalls an experiment): the runtime's ``put``.
publish = put


class Recorder:
    """Every message on some keys, decoded, with its arrival time (``time.monotonic``): one
    ``Collector`` per name."""

    def __init__(self, session: Any, keys: dict[str, tuple[str, type[Message]]]):
        self._collectors = {name: Collector(session, key, msg_type) for name, (key, msg_type) in keys.items()}

    def snapshot(self, name: str) -> list[tuple[float, Any]]:
        return self._collectors[name].snapshot()

    def clear(self) -> None:
        for c in self._collectors.values():
            c.clear()

    def close(self) -> None:
        for c in self._collectors.values():
            c.close()


@contextlib.contextmanager
def recording(session: Any, keys: dict[str, tuple[str, type[Message]]]) -> Iterator[Recorder]:
    rec = Recorder(session, keys)
    try:
        yield rec
    finally:
        rec.close()
