"""The thin node every service is: decode → call the core → encode → publish.

One ``Node`` owns one Zenoh session, a liveliness token ``{prefix}/{robot}/alive/{service}`` (declared once it serves),
per-key counters published as ``NodeStatus`` on ``{prefix}/{robot}/status/{service}``, and
a single loop thread that runs every handler and timer. Because handlers never run
concurrently, a service's core needs no locks. Bad input never reaches a handler: it is
counted, logged at most once per period and dropped, and the node keeps serving.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import numpy as np
import zenoh

from riskfield.protocol import ENCODING, DecodeError, Keys, Limits, Message, NodeStatus, decode, encode
from riskfield.protocol.keys import base_of, qos_of

from .inbox import Inbox, QueueKind, Slot
from .logs import RateLimitedLog, process_age_s, setup_logging
from .memory import HeapTrimmer
from .session import open_session
from .settings import NodeSettings
from .signals import catch_stop_signals

M = TypeVar("M", bound=Message)
_ENC = zenoh.Encoding(ENCODING)


def _entity(gid: Any) -> str:
    """``<zid>/<eid>`` of a zenoh ``EntityGlobalId``."""
    return f"{gid.zid}/{gid.eid}"


#: A ``latest`` subscription on a wildcard keeps the newest sample of each of this many keys
#: (cmd/ref/<source>: one per source), the rest share one slot: the count of slots stays bounded
#: whatever keys a publisher makes up.
KEYED_SLOTS = 16


class _Sub:
    """A subscription's slot plus how to decode and whom to call. With ``keyed`` (a wildcard
    ``latest`` subscription) each sample key gets a latest slot of its own, up to ``KEYED_SLOTS``:
    slots are served round-robin, so one source's stream never displaces another's newest value."""

    def __init__(self, key: str, slot: Slot, msg_type: type[Message] | None, handler: Callable, limits: Limits,
                 keyed: Callable[[str], Slot] | None = None):
        self.key, self.slot, self.msg_type, self.handler, self.limits = key, slot, msg_type, handler, limits
        slot.owner = self
        self.invalid = 0
        self.foreign = 0  # samples dropped because their key is not one this subscription serves
        self._keyed, self._lock = keyed, threading.Lock()
        self.by_key: dict[str, Slot] = {}

    def slot_for(self, key: str) -> Slot:
        if self._keyed is None:
            return self.slot
        with self._lock:  # Zenoh may call back from several threads
            slot = self.by_key.get(key)
            if slot is None and len(self.by_key) < KEYED_SLOTS:
                slot = self.by_key[key] = self._keyed(key)
                slot.owner = self
        return self.slot if slot is None else slot

    @property
    def slots(self) -> list[Slot]:
        with self._lock:
            return [self.slot, *self.by_key.values()]


def compile_watch() -> Any:
    """The process's ``jit.CompileWatch`` once numba is loaded, else None: importing ``jit`` loads
    numba, which a node without kernels (router, operator, bridges) must not pay for."""
    if "numba" not in sys.modules:
        return None
    from . import jit

    return jit.watch_compiles()


def serves(sub_key: str, sample_key: str) -> bool:
    """Whether a sample on ``sample_key`` may reach a subscription declared on ``sub_key``.

    Zenoh delivers a put on any key expression that *intersects* the subscription, so a put on
    ``rf/limo1/cmd/*`` or ``**`` reaches a ``rf/limo1/cmd/safe`` subscriber with the
    publisher's wildcard key (zenoh ``Sample.key_expr`` is the put's expression). A concrete
    subscription therefore serves exactly its own key; a wildcard one (recorders) serves only
    concrete keys, never a wildcard put (``*``, ``**`` and ``$*`` all contain ``*``).
    """
    if "*" in sub_key:
        return "*" not in sample_key
    return sample_key == sub_key


class Node:
    """Runtime of one service. Build it, declare subscriptions/timers, then ``run()``."""

    def __init__(self, service: str, settings: NodeSettings, *, session: zenoh.Session | None = None):
        self.service = service
        self.settings = settings
        self.keys = Keys(robot=settings.robot, prefix=settings.prefix)
        self.log = setup_logging(service, settings.log_level)
        self.ratelog = RateLimitedLog(self.log)
        self.stats: dict[str, float] = {}  # extra numbers a service wants in its NodeStatus
        self.status_fields: dict[str, Any] = {}  # optional NodeStatus fields a service sets (risk_version, ...)
        self.arrival_ns = 0  # wall-clock arrival time of the message being handled
        # Zenoh source of the message being handled ("<zid>/<eid>" of its publisher), or None
        # when the publisher set no source info (foreign clients); see ``publish``.
        self.source_id: str | None = None
        self._own_session = session is None
        self.session = session if session is not None else open_session(settings)
        self._inbox = Inbox()
        self._calls = self._inbox.slot("calls", "fifo", 10000)
        self._close_hooks: list[Callable[[], None]] = []
        self._subs: list[_Sub] = []
        self._declared: list[Any] = []
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._published: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self._timers: list[tuple[float, int, float, Callable[[], None]]] = []
        self._tick = itertools.count()
        self._durations: deque[float] = deque(maxlen=2000)
        self._errors = 0
        self._stop = threading.Event()
        self.stop_reason = ""
        self._t0 = time.monotonic()
        self._closed = False
        # Declared when the loop starts (``run``), after the service's setup: "alive" then means
        # subscribed, warmed up (a compiled filter step) and serving, which is what a launcher
        # waiting for readiness, a supervisor or an operator needs to know.
        self._token: Any = None
        self.every(settings.status_period_s, self._publish_status)
        self._heap = HeapTrimmer()
        if settings.heap_trim_s > 0 and self._heap.available:
            self.every(settings.heap_trim_s, self._heap)

    # -- declarations -----------------------------------------------------------------------
    def backlog(self, key: str) -> int:
        """How many samples of the subscription on ``key`` wait behind the one being handled: a
        handler of a ``fifo`` stream can skip a superseded item when only the newest matters."""
        return sum(len(slot.items) for sub in self._subs if sub.key == key for slot in sub.slots)

    def subscribe(
        self,
        key: str,
        msg_type: type[M] | None,
        handler: Callable[[M], None] | Callable[[str, bytes], None],
        *,
        queue: QueueKind = "latest",
        maxlen: int = 1000,
        max_bytes: int = 0,
        limits: Limits | None = None,
    ) -> None:
        """Call ``handler(msg)`` on the loop thread for each valid message on ``key``.

        With ``msg_type=None`` the handler gets ``(key, payload_bytes)`` undecoded (recorders).
        A ``fifo`` queue holds at most ``maxlen`` samples and, with ``max_bytes``, that many
        payload bytes (inbox.py); the oldest go first, counted in ``NodeStatus.dropped``.
        """
        keyed = (lambda k: self._inbox.slot(k, "latest")) if queue == "latest" and "*" in key else None
        sub = _Sub(key, self._inbox.slot(key, queue, maxlen, max_bytes), msg_type, handler, limits or Limits(), keyed)
        self._subs.append(sub)

        def on_sample(sample: zenoh.Sample, sub: _Sub = sub) -> None:
            key = str(sample.key_expr)
            # Dropped here, before the queue: a forged wildcard put must not displace the
            # legitimate newest value of a latest-value queue.
            if not serves(sub.key, key):
                sub.foreign += 1
                self.ratelog(logging.WARNING, f"foreign:{sub.key}",
                             f"dropped a sample on {key}: this subscription serves only {sub.key}")
                return
            info = sample.source_info
            source = None if info is None else _entity(info.source_id)
            payload = sample.payload.to_bytes()
            self._inbox.put(sub.slot_for(key), ("sample", key, payload, time.time_ns(), source), len(payload))

        self._declared.append(self.session.declare_subscriber(key, on_sample))

    def queryable(
        self,
        key: str,
        request_type: type[M],
        handler: Callable[[M], Message],
        *,
        limits: Limits | None = None,
    ) -> None:
        """Answer queries on ``key``: the request payload is decoded as ``request_type`` and
        ``handler`` returns the reply message; a bad request gets an error reply."""
        sub = _Sub(key, self._inbox.slot(key, "fifo", 256), request_type, handler, limits or Limits())
        self._subs.append(sub)

        def on_query(query: zenoh.Query, sub: _Sub = sub) -> None:
            self._inbox.put(sub.slot, ("query", query, None, time.time_ns(), None))

        self._declared.append(self.session.declare_queryable(key, on_query))

    def post(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on the loop thread as soon as possible; safe to call from any thread
        (device readers, serial threads), so cores still see one thread only."""
        self._inbox.put(self._calls, ("call", fn, None, time.time_ns(), None))

    def on_close(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` at shutdown while the session is still open (a bridge's last stop command)."""
        self._close_hooks.append(fn)

    def every(self, period_s: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` on the loop thread every ``period_s`` seconds (no catch-up bursts)."""
        heapq.heappush(self._timers, (time.monotonic() + period_s, next(self._tick), period_s, fn))

    # -- output -------------------------------------------------------------------------------
    def publish(self, key: str, msg: Message) -> None:
        """Stamp the header's sequence number, encode (refusing NaN/Inf) and put.

        The sample carries Zenoh source info (this publisher's entity id and the same sequence
        number), which tells a receiver which publisher a message came from: a ``seq`` going
        backwards from one publisher is a replay, a new publisher (a restarted node) is not."""
        seq = self._seq.get(key, 0)
        msg.header.seq = seq
        payload = encode(msg)
        pub = self._publishers.get(key) or self._declare_publisher(key, _ENC)
        pub.put(payload, source_info=zenoh.SourceInfo(pub.id, seq))
        self._seq[key] = seq + 1
        self._published[key] = self._published.get(key, 0) + 1

    def publish_raw(self, key: str, payload: bytes, encoding: str = ENCODING) -> None:
        """Put bytes as they are (replays, foreign encodings such as ROS 2 CDR)."""
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._declare_publisher(key, _ENC if encoding == ENCODING else zenoh.Encoding(encoding))
        # A replay or relay is a publisher of its own, whatever publisher the bytes came from.
        pub.put(payload, source_info=zenoh.SourceInfo(pub.id, self._published.get(key, 0)))
        self._published[key] = self._published.get(key, 0) + 1

    def _declare_publisher(self, key: str, encoding: zenoh.Encoding) -> zenoh.Publisher:
        """The one publisher of ``key``, with the key's QoS (``riskfield.protocol.keys.QOS``).

        zenoh-python ``Session.declare_publisher(key, priority=, congestion_control=, express=)``
        (eclipse-zenoh/zenoh-python, src/session.rs) sets them on every sample it puts; routers
        forward a sample with the QoS it came with (eclipse-zenoh/zenoh,
        zenoh/src/net/routing/dispatcher/pubsub.rs, ``ext_qos: msg.ext_qos``), and each link has one
        transmission queue per priority (DEFAULT_CONFIG.json5, ``transport/link/tx/queue/size``), so a
        command overtakes an image that waits for a slow link, and a droppable image is dropped when
        its queue stays full (``congestion_control/drop/wait_before_drop``) rather than stall it."""
        q = qos_of(self.keys.relative(key))
        pub = self.session.declare_publisher(
            key, encoding=encoding, priority=getattr(zenoh.Priority, q.priority.upper()),
            congestion_control=zenoh.CongestionControl.DROP if q.drop else zenoh.CongestionControl.BLOCK,
            express=q.express)
        self._publishers[key] = pub
        return pub

    def query(self, key: str, request: Message, reply_type: type[M], timeout_s: float = 1.0) -> list[M]:
        """Blocking query (for clients and tools, not for handlers on the loop thread)."""
        out = []
        for reply in self.session.get(key, payload=encode(request), encoding=_ENC, timeout=timeout_s):
            if reply.ok is not None:
                out.append(decode(reply.ok.payload.to_bytes(), reply_type))
        return out

    # -- loop ---------------------------------------------------------------------------------
    def stop(self, reason: str = "stop requested") -> None:
        if not self._stop.is_set():
            self.stop_reason = reason
            self._stop.set()
            self._inbox.wake()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def run(self, duration_s: float | None = None) -> int:
        """Serve until SIGINT/SIGTERM, ``stop()`` or ``duration_s``; close; return 0."""
        restore = catch_stop_signals(self.stop)
        end = None if duration_s is None else time.monotonic() + duration_s
        if self._token is None:
            self._token = self.session.liveliness().declare_token(self.keys.alive(self.service))
        self.log.info("%s up as %s on %s (robot %s), %.1f s after spawn", self.service, self.settings.mode,
                      ", ".join(self.settings.connect or self.settings.listen), self.settings.robot, process_age_s())
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if end is not None and now >= end:
                    break
                timeout = 0.5
                if self._timers:
                    timeout = max(0.0, min(timeout, self._timers[0][0] - now))
                if end is not None:
                    timeout = max(0.0, min(timeout, end - now))
                item = self._inbox.get(timeout)
                if item is not None:
                    self._dispatch(*item)
                self._run_due_timers()
        finally:
            restore()
            self.close()
        self.log.info("%s stopped (%s)", self.service, self.stop_reason or "done")
        return 0

    def _run_due_timers(self) -> None:
        now = time.monotonic()
        while self._timers and self._timers[0][0] <= now:
            due, _, period, fn = heapq.heappop(self._timers)
            nxt = due + period
            heapq.heappush(self._timers, (nxt if nxt > now else now + period, next(self._tick), period, fn))
            self._call(f"timer {getattr(fn, '__name__', fn)}", fn)

    def _dispatch(self, slot: Slot, item: tuple) -> None:
        kind, a, b, self.arrival_ns, self.source_id = item
        if kind == "call":
            self._call(f"posted {getattr(a, '__name__', a)}", a)
            return
        sub = slot.owner
        if kind == "query":
            self._answer(sub, a)
            return
        key, payload = a, b
        if sub.msg_type is None:
            self._call(key, sub.handler, key, payload)
            return
        try:
            msg = decode(payload, sub.msg_type, sub.limits)
        except DecodeError as exc:
            sub.invalid += 1
            self.ratelog(logging.WARNING, f"invalid:{sub.key}", f"rejected a message on {key}: {exc}")
            return
        self._call(key, sub.handler, msg)

    def _answer(self, sub: _Sub, query: zenoh.Query) -> None:
        try:
            payload = query.payload
            if payload is None:
                raise DecodeError("the query carries no payload")
            request = decode(payload.to_bytes(), sub.msg_type, sub.limits)
        except DecodeError as exc:
            sub.invalid += 1
            self.ratelog(logging.WARNING, f"invalid:{sub.key}", f"rejected a query on {sub.key}: {exc}")
            query.reply_err(str(exc).encode())
            query.drop()
            return
        reply = self._call(sub.key, sub.handler, request)
        try:
            if isinstance(reply, Message):
                query.reply(query.key_expr, encode(reply), encoding=_ENC)
                self._published[sub.key] = self._published.get(sub.key, 0) + 1
            else:
                query.reply_err(b"the service could not answer this query")
        finally:
            query.drop()

    def _call(self, what: str, fn: Callable, *args: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return fn(*args)
        except Exception as exc:  # a bug or bad data in one message must not stop the node
            self._errors += 1
            self.ratelog(logging.ERROR, f"error:{what}", f"handler for {what} failed: {exc!r}", exc_info=True)
            return None
        finally:
            self._durations.append(time.perf_counter() - t0)

    # -- status -------------------------------------------------------------------------------
    def status(self) -> NodeStatus:
        d = np.asarray(self._durations, dtype=float) * 1e3 if self._durations else np.zeros(1)
        def per_key(counts: Iterable[tuple[str, int]]) -> dict[str, int]:
            # Counted per contract key: cmd/ref/<source>, and a subscription on cmd/ref/**, count as
            # cmd/ref (protocol.keys.base_of).
            out: dict[str, int] = {}
            for key, n in counts:
                relative = self.keys.relative(key)
                name = key if relative is None else base_of(relative)
                out[name] = out.get(name, 0) + n
            return out

        extra = {k: float(v) for k, v in self.stats.items() if np.isfinite(v)}
        # Wildcard (or otherwise foreign-keyed) puts dropped by the runtime, all subscriptions.
        extra["wildcard_dropped"] = extra.get("wildcard_dropped", 0.0) + sum(s.foreign for s in self._subs)
        extra["heap_trimmed_kb"] = float(self._heap.released_kb)
        watch = compile_watch()
        if watch is not None:  # kernels compiled in this process: 0 after `riskfield warmup`
            extra["kernels_compiled"] = float(watch.compiled)
        return NodeStatus(
            service=self.service,
            pid=os.getpid(),
            uptime_s=time.monotonic() - self._t0,
            received=per_key((s.key, sum(x.received for x in s.slots)) for s in self._subs),
            invalid=per_key((s.key, s.invalid) for s in self._subs),
            dropped=per_key((s.key, sum(x.dropped for x in s.slots)) for s in self._subs),
            published=per_key(self._published.items()),
            errors=self._errors,
            handler_ms_p50=float(np.percentile(d, 50)),
            handler_ms_p99=float(np.percentile(d, 99)),
            handler_ms_max=float(d.max()),
            extra=extra,
            **self.status_fields,
        )

    def _publish_status(self) -> None:
        self.publish(self.keys.status(self.service), self.status())

    # -- shutdown -----------------------------------------------------------------------------
    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for hook in self._close_hooks:
            self._call(f"close hook {getattr(hook, '__name__', hook)}", hook)
        self._inbox.close()
        for d in self._declared:
            try:
                d.undeclare()
            except Exception:
                pass
        for p in self._publishers.values():
            try:
                p.undeclare()
            except Exception:
                pass
        try:
            if self._token is not None:
                self._token.undeclare()
        except Exception:
            pass
        if self._own_session:
            self.session.close()

    def __enter__(self) -> Node:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
