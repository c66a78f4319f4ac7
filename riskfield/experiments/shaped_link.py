"""A bad link in user space: a TCP relay on loopback between two Zenoh routers that shapes each
direction like a robot's Wi-Fi (the kernels here have no ``netem``).

Each direction is a FIFO of the bytes read from one side, written to the other:

- **rate**: a token bucket (``rate_bps``, bursts of ``burst_bytes``) paces the writes;
- **delay and jitter**: a chunk read at *t* leaves no sooner than *t* + ``delay_s`` ± ``jitter_s``
  (uniform), and never before the chunk ahead of it: a TCP stream stays in order, as on a real
  link, where jitter delays what follows too;
- **a bounded queue**: the relay stops reading while ``queue_bytes`` wait to be written, so the
  backlog builds up in the sender's own queues (Zenoh's, per priority), where the sender decides
  what waits and what is dropped, not in an unbounded buffer here. The relay's sockets have small
  kernel buffers for the same reason;
- **stalls and cuts**: ``stall()`` stops both directions (bytes held, nothing lost, the
  connections stay up) until ``resume()``; ``cut()`` closes every connection and refuses new ones
  until ``restore()``, as a robot that drives out of the access point's range.

Parameters can change while it runs (``shape``), so one test compares the same routers and
connections unshaped and shaped.
"""

from __future__ import annotations

import contextlib
import random
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field

_CHUNK = 16 * 1024
#: Kernel buffers of the relay's sockets: small, so the backlog is the relay's queue (bounded,
#: measured) and the senders', not megabytes of autotuned socket buffer.
_SOCKBUF = 32 * 1024


@dataclass
class Shape:
    rate_bps: float = float("inf")  # bits per second, each direction
    delay_s: float = 0.0
    jitter_s: float = 0.0
    burst_bytes: int = 16 * 1024
    queue_bytes: int = 256 * 1024


@dataclass
class DirectionStats:
    bytes: int = 0
    max_queued: int = 0
    delays_ms: deque[float] = field(default_factory=lambda: deque(maxlen=100000))


class _Pipe:
    """One direction of one connection: reader thread → bounded FIFO → paced writer thread."""

    def __init__(self, link: ShapedLink, src: socket.socket, dst: socket.socket, stats: DirectionStats):
        self.link, self.src, self.dst, self.stats = link, src, dst, stats
        self.queue: deque[tuple[float, float, bytes]] = deque()  # (read at, due, bytes)
        self.queued = 0
        self.cond = threading.Condition()
        self.closed = False
        self.tokens = 0.0
        self.last_refill = time.monotonic()
        self.last_due = 0.0
        self.threads = [threading.Thread(target=self._read, daemon=True),
                        threading.Thread(target=self._write, daemon=True)]
        for t in self.threads:
            t.start()

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()
        for s in (self.src, self.dst):
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)

    def _read(self) -> None:
        try:
            while True:
                with self.cond:
                    while not self.closed and self.queued >= self.link.shape.queue_bytes:
                        self.cond.wait(0.05)
                    if self.closed:
                        return
                data = self.src.recv(_CHUNK)
                if not data:
                    return
                now = time.monotonic()
                sh = self.link.shape
                due = now + sh.delay_s + (self.link.rng.uniform(-sh.jitter_s, sh.jitter_s) if sh.jitter_s else 0.0)
                with self.cond:
                    due = max(due, self.last_due)
                    self.last_due = due
                    self.queue.append((now, due, data))
                    self.queued += len(data)
                    self.stats.max_queued = max(self.stats.max_queued, self.queued)
                    self.cond.notify_all()
        except OSError:
            pass
        finally:
            self.link._drop(self)

    def _take(self, n: int) -> float:
        """Wait for ``n`` tokens of the bucket; the time it took."""
        t0 = time.monotonic()
        while True:
            sh = self.link.shape
            if sh.rate_bps == float("inf"):
                return time.monotonic() - t0
            now = time.monotonic()
            self.tokens = min(sh.burst_bytes, self.tokens + (now - self.last_refill) * sh.rate_bps / 8)
            self.last_refill = now
            if self.tokens >= n:
                self.tokens -= n
                return now - t0
            time.sleep((n - self.tokens) * 8 / sh.rate_bps)

    def _write(self) -> None:
        try:
            while True:
                with self.cond:
                    while not self.closed and (not self.queue or self.link.stalled):
                        self.cond.wait(0.05)
                    if self.closed:
                        return
                    read_at, due, data = self.queue[0]
                wait = due - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                for i in range(0, len(data), self.link.shape.burst_bytes):
                    piece = data[i:i + self.link.shape.burst_bytes]
                    self._take(len(piece))
                    # Counted before it is written: a reader that has the bytes finds them counted (counted
                    # after, the last piece's count raced the receiver's read: CI saw a map stream's bytes short).
                    self.stats.bytes += len(piece)
                    try:
                        self.dst.sendall(piece)
                    except OSError:
                        self.stats.bytes -= len(piece)
                        raise
                with self.cond:
                    self.queue.popleft()
                    self.queued -= len(data)
                    self.cond.notify_all()
                self.stats.delays_ms.append((time.monotonic() - read_at) * 1e3)
        except OSError:
            pass
        finally:
            self.link._drop(self)


class ShapedLink:
    """``127.0.0.1:port`` → ``target``, shaped. Use as a context manager; ``endpoint`` is the Zenoh
    endpoint to dial instead of the target's."""

    def __init__(self, target_port: int, shape: Shape | None = None, seed: int = 0):
        self.target = ("127.0.0.1", target_port)
        self.shape = shape or Shape()
        self.rng = random.Random(seed)
        self.stalled = False
        self.refusing = False
        self.up = DirectionStats()  # dialler → target (the robot's router → the server's)
        self.down = DirectionStats()
        self.connections = 0
        self._pipes: list[_Pipe] = []
        self._lock = threading.Lock()
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _SOCKBUF)  # accepted sockets inherit it
        self._listener.bind(("127.0.0.1", 0))
        self.port = self._listener.getsockname()[1]
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self._closed = False
        self._acceptor = threading.Thread(target=self._accept, daemon=True)

    def __enter__(self) -> ShapedLink:
        self._listener.listen(16)
        self._acceptor.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._closed = True
        with contextlib.suppress(OSError):
            self._listener.close()
        self._close_all()

    def shaped(self, shape: Shape) -> None:
        """New parameters, from the next chunk on."""
        self.shape = shape

    def stall(self) -> None:
        self.stalled = True

    def resume(self) -> None:
        self.stalled = False

    def cut(self) -> None:
        """Close every connection and refuse new ones until ``restore``."""
        self.refusing = True
        self._close_all()

    def restore(self) -> None:
        self.refusing = False

    @property
    def queued(self) -> int:
        with self._lock:
            return sum(p.queued for p in self._pipes)

    def _close_all(self) -> None:
        with self._lock:
            pipes, self._pipes = self._pipes, []
        for p in pipes:
            p.close()

    def _drop(self, pipe: _Pipe) -> None:
        """One direction ended: end the connection (both directions), as TCP would."""
        pipe.close()
        with self._lock:
            peers = [p for p in self._pipes if p.src in (pipe.src, pipe.dst)]
            self._pipes = [p for p in self._pipes if p not in peers]
        for p in peers:
            p.close()

    def _accept(self) -> None:
        while not self._closed:
            try:
                conn, _ = self._listener.accept()
            except OSError:
                return
            if self.refusing:
                conn.close()
                continue
            try:
                out = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                out.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, _SOCKBUF)
                out.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _SOCKBUF)
                out.connect(self.target)
            except OSError:
                conn.close()
                continue
            for s in (conn, out):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, _SOCKBUF)
            with self._lock:
                self.connections += 1
                self._pipes += [_Pipe(self, conn, out, self.up), _Pipe(self, out, conn, self.down)]
