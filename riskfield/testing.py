"""Helpers for testing a service in isolation over a real Zenoh router on loopback.

    with ZenohRouter() as router, ServiceProcess("relay", router.endpoint) as relay:
        with client_session(router.endpoint) as session:
            ...

Everything stays on 127.0.0.1 with multicast scouting off, and every session is closed.
Child services are separate interpreters (``python -m riskfield run ...``): never fork a
process that holds a Zenoh session.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import zenoh

from riskfield.protocol import ENCODING, Message, decode, encode


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def client_config(endpoint: str, mode: str = "client") -> zenoh.Config:
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return cfg


class ZenohRouter:
    """A Python Zenoh router session on a free loopback port (what `riskfield run router` runs)."""

    def __init__(self, port: int | None = None):
        self.port = port or free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.session: zenoh.Session | None = None

    def __enter__(self) -> ZenohRouter:
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"router"')
        cfg.insert_json5("listen/endpoints", json.dumps([self.endpoint]))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(cfg)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None


@contextlib.contextmanager
def client_session(endpoint: str) -> Iterator[zenoh.Session]:
    session = zenoh.open(client_config(endpoint))
    try:
        yield session
    finally:
        session.close()


def put(session: zenoh.Session, key: str, msg: Message | bytes) -> None:
    payload = msg if isinstance(msg, (bytes, bytearray)) else encode(msg)
    session.put(key, bytes(payload), encoding=zenoh.Encoding(ENCODING))


class Collector:
    """Subscribes to a key and keeps every decoded message (or raw payload) it sees."""

    def __init__(self, session: zenoh.Session, key: str, msg_type: type[Message] | None = None):
        self.items: list[Any] = []
        self.keys: list[str] = []
        self._lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            raw = sample.payload.to_bytes()
            item = decode(raw, msg_type) if msg_type is not None else raw
            with self._lock:
                self.items.append(item)
                self.keys.append(str(sample.key_expr))

        self._sub = session.declare_subscriber(key, on_sample)

    def wait(self, n: int = 1, timeout_s: float = 10.0) -> list[Any]:
        if not wait_until(lambda: len(self.items) >= n, timeout_s):
            raise TimeoutError(f"got {len(self.items)} of {n} messages in {timeout_s} s")
        with self._lock:
            return list(self.items)

    def clear(self) -> None:
        with self._lock:
            self.items.clear()
            self.keys.clear()

    def close(self) -> None:
        self._sub.undeclare()


def wait_until(predicate: Callable[[], bool], timeout_s: float = 10.0, period_s: float = 0.02) -> bool:
    """Poll ``predicate`` until it holds or ``timeout_s`` passes (bounded, never infinite)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(period_s)
    return bool(predicate())


class ServiceProcess:
    """``riskfield run NAME --connect ENDPOINT ARGS...`` in its own interpreter, output to a file."""

    def __init__(self, name: str, endpoint: str, args: Sequence[str] = (), env: dict[str, str] | None = None):
        self.name = name
        flag = "--listen" if name == "router" else "--connect"
        self.argv = [sys.executable, "-m", "riskfield", "run", name, flag, endpoint, *args]
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self._log = tempfile.NamedTemporaryFile(prefix=f"rf-{name}-", suffix=".log", delete=False)  # noqa: SIM115
        self.proc: subprocess.Popen | None = None

    def __enter__(self) -> ServiceProcess:
        self.proc = subprocess.Popen(self.argv, stdout=self._log, stderr=subprocess.STDOUT, env=self.env)
        return self

    @property
    def output(self) -> str:
        with open(self._log.name, errors="replace") as f:
            return f.read()

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = 15.0) -> int:
        """Signal the process, wait, and return its exit code (kills it if it hangs)."""
        assert self.proc is not None
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise RuntimeError(f"{self.name} ignored signal {sig}; output:\n{self.output}") from None
        return self.proc.returncode

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and self.proc.poll() is None:
            with contextlib.suppress(RuntimeError):
                self.stop()
        self._log.close()
        with contextlib.suppress(OSError):
            os.unlink(self._log.name)


def wait_alive(session: zenoh.Session, key: str, timeout_s: float = 20.0) -> bool:
    """Wait until a liveliness token on ``key`` is visible (a node is up and connected)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        replies = list(session.liveliness().get(key, timeout=0.5))
        if any(r.ok is not None for r in replies):
            return True
        time.sleep(0.1)
    return False
