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
import itertools
import signal
import subprocess
import threading
from collections.abc import Callable, Sequence

import zenoh

from riskfield.protocol import Message, NodeStatus, decode, encode
from riskfield.services.runtime.client import Collector, put
from riskfield.services.runtime.processes import (  # noqa: F401  (re-exported test API)
    Child,
    EmbeddedRouter,
    client_session,
    free_port,
    service_argv,
    wait_alive,
    wait_until,
)
from riskfield.services.runtime.session import endpoint_config


def client_config(endpoint: str, mode: str = "client") -> zenoh.Config:
    return endpoint_config(mode, [endpoint])


class ZenohRouter(EmbeddedRouter):
    """A Python Zenoh router session on a free loopback port (what `riskfield run router` runs);
    the runtime's ``EmbeddedRouter`` under its test name."""


def open_when_ready(open_fn: Callable[[], zenoh.Session], timeout_s: float = 20.0,
                    alive: ServiceProcess | None = None) -> zenoh.Session:
    """``open_fn()``, retried while it fails with ``zenoh.ZError`` (the router it dials is still
    starting), for at most ``timeout_s``; with ``alive``, a router process that died fails at once."""
    sessions: list[zenoh.Session] = []

    def opened() -> bool:
        if alive is not None and not alive.alive():
            raise RuntimeError(f"{alive.name} exited:\n{alive.output}")
        with contextlib.suppress(zenoh.ZError):
            sessions.append(open_fn())
        return bool(sessions)

    if not wait_until(opened, timeout_s, period_s=0.1):
        raise TimeoutError(f"no session in {timeout_s} s" + (f"; output:\n{alive.output}" if alive else ""))
    return sessions[0]


def wait_matched(session: zenoh.Session, key: str, timeout_s: float = 10.0) -> bool:
    """Wait until ``session`` knows a subscriber matching ``key``, i.e. a put from it now reaches
    that subscriber (declarations propagate through the router asynchronously; a put sent before
    they arrive is not routed to the new subscriber). Uses the publisher's matching status."""
    pub = session.declare_publisher(key)
    try:
        return wait_until(lambda: pub.matching_status.matching, timeout_s)
    finally:
        pub.undeclare()


def query_barrier(sender: zenoh.Session, receiver: zenoh.Session, timeout_s: float = 10.0) -> bool:
    """An ordering barrier from ``sender`` to ``receiver``: True once a query sent by ``sender``
    reached a queryable of ``receiver``. Messages of one session travel its links in order, so
    every put ``sender`` made before the call that was going to reach ``receiver`` has reached
    it by then. This is how a test sees that a denied or dropped put never arrives, without
    waiting for a fixed time."""
    key = f"rf_test/barrier/{next(_BARRIER_IDS)}"
    hits = threading.Event()
    queryable = receiver.declare_queryable(key, lambda _query: hits.set())
    try:
        # Retried: the queryable's declaration reaches the sender asynchronously.
        return wait_until(lambda: (sender.get(key, timeout=0.5), hits.is_set())[1], timeout_s, period_s=0.05)
    finally:
        queryable.undeclare()


_BARRIER_IDS = itertools.count()


class StatusWatch:
    """Keeps the ``NodeStatus`` a service publishes on ``{prefix}/{robot}/status/{service}`` and
    waits on its counters (run the service with ``--set status_period_s=0.1`` to hear it often)."""

    def __init__(self, session: zenoh.Session, key: str):
        self._collector = Collector(session, key, NodeStatus)

    @property
    def latest(self) -> NodeStatus | None:
        items = self._collector.items
        return items[-1] if items else None

    def wait(self, predicate: Callable[[NodeStatus], bool], timeout_s: float = 10.0) -> NodeStatus:
        """The first status (from now on, or the latest one) for which ``predicate`` holds."""
        if not wait_until(lambda: (st := self.latest) is not None and predicate(st), timeout_s):
            raise TimeoutError(f"no status satisfied the condition in {timeout_s} s; last: {self.latest}")
        status = self.latest
        assert status is not None
        return status

    def close(self) -> None:
        self._collector.close()


class ServiceProcess:
    """``riskfield run NAME --connect ENDPOINT ARGS...`` in its own interpreter, output kept.

    The runtime's process (``services/runtime/processes.py``: spawn model, output pumped into
    memory) with the test API: a stop that fails the test if the service ignored the signal."""

    def __init__(self, name: str, endpoint: str, args: Sequence[str] = (), env: dict[str, str] | None = None):
        self.name = name
        flag = "--listen" if name == "router" else "--connect"
        self._child = Child(name, name, service_argv(name, [flag, endpoint, *args]), env=env)
        self.argv = self._child.argv
        self.env = self._child.env

    @property
    def proc(self) -> subprocess.Popen | None:
        return self._child.proc

    def __enter__(self) -> ServiceProcess:
        self._child.start()
        return self

    @property
    def output(self) -> str:
        return self._child.output

    def alive(self) -> bool:
        return self._child.alive()

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = 15.0) -> int:
        """Signal the process, wait, and return its exit code (kills it if it hangs)."""
        code, escalated = self._child.stop(sig, timeout_s)
        if escalated:
            raise RuntimeError(f"{self.name} ignored signal {sig} (needed {escalated}); output:\n{self.output}")
        assert code is not None
        return code

    def __exit__(self, *exc: object) -> None:
        if self.alive():
            with contextlib.suppress(RuntimeError):
                self.stop()
        self._child.join_output()


def put_each_rejected(session: zenoh.Session, key: str, payloads: Sequence[bytes], status: StatusWatch,
                      counter: str, timeout_s: float = 10.0) -> int:
    """Put each payload, then wait until the node's ``invalid[counter]`` has counted it before
    sending the next (a latest-value queue would otherwise skip some of them undecoded), so
    every one of them is decoded and rejected. Returns the final invalid count."""
    count = status.latest.invalid.get(counter, 0) if status.latest is not None else 0
    for payload in payloads:
        put(session, key, payload)
        count = status.wait(lambda st, n=count: st.invalid.get(counter, 0) > n, timeout_s).invalid[counter]
    return count


def hostile_payloads(valid: Message, n: int = 1000, seed: int = 0) -> list[bytes]:
    """``n`` payloads a receiver must reject, derived from one valid message: random bytes,
    truncated msgpack, wrong or unknown schema, NaN/Inf, giant declared shapes, wrong dtypes,
    missing fields, wrong types. Deterministic for a seed."""
    import msgpack
    import numpy as np

    from riskfield.protocol import to_map

    rng = np.random.default_rng(seed)
    good = encode(valid)
    base = to_map(valid)
    arrays = [k for k, v in base.items() if isinstance(v, dict) and {"dtype", "shape", "data"} <= v.keys()]
    scalars = [k for k, v in base.items() if k not in ("schema", "header") and k not in arrays]

    def pack(m: dict) -> bytes:
        return msgpack.packb(m, use_bin_type=True)

    def mutate(kind: int) -> bytes:
        m = dict(base)
        if kind == 0:
            return rng.bytes(int(rng.integers(0, 256)))
        if kind == 1:
            return good[: int(rng.integers(0, max(1, len(good) - 1)))]
        if kind == 2:
            m["schema"] = str(rng.choice(["Nope/1", "", "VelocityCommand/9", "Image/1" if valid.SCHEMA != "Image/1"
                                          else "RobotState/1"]))
            return pack(m)
        if kind == 3 and arrays:
            k = str(rng.choice(arrays))
            a = dict(m[k])
            a["shape"] = [(2**40)] * max(1, len(a["shape"]))
            m[k] = a
            return pack(m)
        if kind == 4 and arrays:
            k = str(rng.choice(arrays))
            a = dict(m[k])
            a["dtype"] = str(rng.choice(["<f8", "<i4", ">f4", "|u1", "<c16", "O"]))
            if a["dtype"] == m[k]["dtype"]:
                a["dtype"] = "<i8"
            m[k] = a
            return pack(m)
        if kind == 5:
            targets = [k for k in scalars if isinstance(base[k], (float, list, tuple))] or arrays
            if not targets:
                return pack({"schema": base["schema"], "header": {"stamp_ns": "x"}})
            k = str(rng.choice(targets))
            v = m[k]
            if isinstance(v, dict):
                arr = np.frombuffer(bytes(v["data"]), dtype=v["dtype"]).copy()
                if arr.dtype.kind == "f" and arr.size:
                    arr.flat[int(rng.integers(0, arr.size))] = np.nan
                    m[k] = {**v, "data": arr.tobytes()}
                else:
                    m[k] = {**v, "data": b"\x00"}
            elif isinstance(v, (list, tuple)):
                m[k] = [float("nan")] * len(v)
            else:
                m[k] = float("inf")
            return pack(m)
        if kind == 6:
            k = str(rng.choice([*scalars, *arrays, "header"]))
            m.pop(k, None)
            return pack(m)
        if kind == 7:
            k = str(rng.choice([*scalars, *arrays, "header"]))
            m[k] = [  # wrong types
                "text", {"nested": 1}, [1, 2, 3, 4, 5, 6, 7], None][int(rng.integers(0, 4))]
            return pack(m)
        return pack([1, 2, 3]) if kind == 8 else b""

    out = []
    for i in range(n):
        payload = mutate(i % 10)
        try:
            decode(payload, type(valid))
        except Exception:
            out.append(payload)
        else:
            out.append(rng.bytes(17))  # the mutation happened to stay valid: replace by garbage
    return out
