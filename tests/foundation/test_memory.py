"""Heap trimming (runtime/memory.py): freed memory between live blocks goes back to the OS."""

from __future__ import annotations

import threading

import pytest

from riskfield.services.runtime import Node, NodeSettings
from riskfield.services.runtime.memory import HeapTrimmer, rss_kb
from riskfield.testing import wait_until


def test_rss_is_read() -> None:
    assert rss_kb() > 1000  # a Python interpreter with numpy is megabytes


def test_trim_returns_freed_blocks_that_sit_between_live_ones() -> None:
    trim = HeapTrimmer()
    if not trim.available:
        pytest.skip("not glibc: no malloc_trim")
    trim()  # start from a trimmed heap
    # 64 KiB blocks are under glibc's mmap threshold: they come from the heap, and freeing every
    # other one leaves holes that malloc keeps resident (only the top of the heap is returned).
    blocks = [bytearray(64 * 1024) for _ in range(1600)]  # 100 MiB, pages touched (zeroed)
    del blocks[::2]
    released = trim()
    assert released > 20_000, released  # of the ~50 MiB freed in holes
    assert trim.trims == 2 and trim.released_kb >= released
    assert len(blocks) == 800  # the live half is untouched


def test_node_trims_on_its_loop_and_reports_it(router_endpoint) -> None:
    node = Node("trimmed", NodeSettings(connect=[router_endpoint], robot="t_trim", heap_trim_s=0.05))
    if not node._heap.available:
        node.close()
        pytest.skip("not glibc: no malloc_trim")
    thread = threading.Thread(target=node.run, daemon=True)
    thread.start()
    try:
        assert wait_until(lambda: node._heap.trims >= 3, 10)
        assert "heap_trimmed_kb" in node.status().extra
    finally:
        node.stop()
        thread.join(10)
    assert not thread.is_alive()


def test_heap_trim_can_be_switched_off(router_endpoint) -> None:
    node = Node("untrimmed", NodeSettings(connect=[router_endpoint], robot="t_trim", heap_trim_s=0))
    try:
        assert all(fn is not node._heap for *_, fn in node._timers)
    finally:
        node.close()
