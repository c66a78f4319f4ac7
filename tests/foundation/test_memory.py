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


_CHURN = """
import resource, sys
import numpy as np
from riskfield.services.runtime.memory import keep_freed_heap
kept = keep_freed_heap(int(sys.argv[1]))
faults = []
for _ in range(12):  # a 3-D ESDF update's pattern: several MB-sized arrays live at once, then all freed
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    arrays = [np.ones(1 << 20, np.float32) for _ in range(8)]  # 8 × 4 MiB, every page touched
    del arrays
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
print(kept, sorted(faults[4:])[4])
"""


@pytest.mark.parametrize("keep_mb", [0, 256])
def test_kept_freed_heap_serves_the_next_update_without_page_faults(keep_mb: int) -> None:
    """In a fresh process (the policy is process-wide): under glibc's own policy every round of
    large arrays takes fresh pages from the kernel (the top of the heap is trimmed at each free);
    with ``keep_freed_heap`` the next round reuses them."""
    import subprocess
    import sys

    if not HeapTrimmer().available:
        pytest.skip("not glibc")
    out = subprocess.run([sys.executable, "-c", _CHURN, str(keep_mb)], capture_output=True, text=True, timeout=120,
                         check=True).stdout.split()
    kept, faults = out[0] == "True", int(out[1])
    assert kept == (keep_mb > 0)
    if keep_mb:
        assert faults < 100, faults  # 8192 pages per round; none come fresh
    else:
        assert faults > 4000, faults  # the contrast the setting exists for
