"""The shaping relay itself, on loopback TCP: in order and whole, cuts refuse and close, and (slow:
wall-clock) it keeps to its rate and delay."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import pytest

from riskfield.experiments.shaped_link import Shape, ShapedLink
from riskfield.testing import wait_until


@pytest.fixture
def echo() -> Iterator[int]:
    """A loopback echo server; its port."""
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)

    def serve(c: socket.socket) -> None:
        with c:
            while data := c.recv(65536):
                c.sendall(data)

    def accept() -> None:
        while True:
            try:
                c, _ = srv.accept()
            except OSError:
                return
            threading.Thread(target=serve, args=(c,), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    yield srv.getsockname()[1]
    srv.close()


def _round_trip(port: int, payload: bytes) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=20) as c:
        threading.Thread(target=c.sendall, args=(payload,), daemon=True).start()
        got = bytearray()
        while len(got) < len(payload):
            chunk = c.recv(65536)
            if not chunk:
                break
            got += chunk
        return bytes(got)


def test_bytes_arrive_whole_and_in_order_with_jitter(echo: int) -> None:
    payload = bytes(range(256)) * 4000  # 1 MB
    with ShapedLink(echo, Shape(delay_s=0.002, jitter_s=0.002, queue_bytes=64 * 1024)) as link:
        assert _round_trip(link.port, payload) == payload
        # A direction counts a chunk once it has written all of it: the last chunk's count may come
        # just after the client read its bytes.
        assert wait_until(lambda: link.up.bytes == len(payload) and link.down.bytes == len(payload), 10.0), (
            link.up.bytes, link.down.bytes)
        assert link.up.max_queued <= 64 * 1024 + 16 * 1024  # the bound, plus the chunk read last


def test_a_cut_closes_the_connections_and_refuses_until_restored(echo: int) -> None:
    with ShapedLink(echo) as link:
        c = socket.create_connection(("127.0.0.1", link.port), timeout=10)
        c.sendall(b"ping")
        assert c.recv(4) == b"ping"
        link.cut()
        assert c.recv(4) == b""  # closed by the cut
        c.close()
        with socket.create_connection(("127.0.0.1", link.port), timeout=10) as refused:
            assert refused.recv(4) == b""  # accepted and closed: the dialler retries
        link.restore()
        assert _round_trip(link.port, b"back") == b"back"


def test_a_stall_holds_the_bytes_and_loses_none(echo: int) -> None:
    with ShapedLink(echo) as link, socket.create_connection(("127.0.0.1", link.port), timeout=10) as c:
        link.stall()
        c.sendall(b"held")
        while link.queued == 0:  # read into the relay's queue, not written on
            time.sleep(0.001)
        assert link.up.bytes == 0
        link.resume()
        assert c.recv(4) == b"held"


@pytest.mark.slow  # wall-clock: a rate and a delay
def test_rate_and_delay_are_kept(echo: int) -> None:
    payload = b"x" * 500_000
    with ShapedLink(echo, Shape(rate_bps=8e6, delay_s=0.02, jitter_s=0.01)) as link:
        t0 = time.monotonic()
        assert _round_trip(link.port, payload) == payload
        took = time.monotonic() - t0
    # 0.5 MB at 1 MB/s each way, pipelined: ~0.5 s, plus the two delays.
    assert 0.45 <= took <= 1.5, took
    delays = sorted(link.up.delays_ms)
    assert delays[0] >= 10.0 - 1.0
