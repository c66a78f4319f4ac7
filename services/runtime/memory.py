"""Giving freed heap back to the operating system, so a long-running node's RSS is its live memory.

Why: glibc's malloc keeps freed memory in its arenas and returns it to the kernel only from the top
of the main heap. A node that handles large messages from many sessions over its life (the router
forwards every perception frame, and a restarted perception is a new session with new transport
buffers) frees megabytes that sit between live blocks and stay resident: the router's RSS grows
with each perception restart and stays flat between them (``tests/deploy/test_soak.py``):
fragmentation, not a leak.

``malloc_trim(0)`` (glibc >= 2.8) returns every whole free page of every arena with
``madvise(MADV_DONTNEED)``; it costs ~0.02 ms median, 0.6 ms worst on a fragmented 1 GB heap, so a
node calls it every second on its loop (``NodeSettings.heap_trim_s``). On other C libraries (musl,
macOS) there is no such call and ``HeapTrimmer.available`` is False: trimming is a no-op there.

The opposite need: a node that allocates and frees the same large arrays many times a second
(the mapping node's 3-D ESDF: about 25 MB of arrays of 0.5-4 MB per update) should *keep* them
between updates. glibc returns the top of the heap to the kernel at every ``free`` once more than
``M_TRIM_THRESHOLD`` is free there (dynamically twice the mmap threshold, here 8 MB), so each
update would take ~5200 fresh pages from the kernel (page faults and zeroing: about a quarter of a
3-D ESDF update). ``keep_freed_heap`` raises the trim threshold and pins the mmap threshold
(setting either turns glibc's dynamic thresholds off): freed arrays stay in the heap for the next
update; the periodic ``malloc_trim`` still gives everything back once a second.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Callable

_PAGE_KB = os.sysconf("SC_PAGE_SIZE") // 1024 if hasattr(os, "sysconf") else 4


def _libc(name: str, argtypes: list, restype: type) -> Callable[..., int] | None:
    """A function of this process's C library, typed; None where it has none (not glibc)."""
    try:
        fn = getattr(ctypes.CDLL(None), name, None)
    except OSError:
        return None
    if fn is None:
        return None
    fn.argtypes = argtypes
    fn.restype = restype
    return fn


def _malloc_trim() -> Callable[[int], int] | None:
    return _libc("malloc_trim", [ctypes.c_size_t], ctypes.c_int)


_M_TRIM_THRESHOLD = -1  # glibc malloc.h
_M_MMAP_THRESHOLD = -3
_MMAP_THRESHOLD_MAX = 32 << 20  # glibc's ceiling for M_MMAP_THRESHOLD on 64-bit (HEAP_MAX_SIZE / 2)


def keep_freed_heap(keep_mb: int) -> bool:
    """Let this process keep up to ``keep_mb`` MB of freed heap for reuse (see the module
    docstring): arrays up to 32 MB come from the heap and freeing them does not trim it. False
    (nothing changed) for 0 or where there is no glibc ``mallopt``."""
    mallopt = _libc("mallopt", [ctypes.c_int, ctypes.c_int], ctypes.c_int) if keep_mb > 0 else None
    if mallopt is None:
        return False
    keep = min(int(keep_mb) << 20, (1 << 31) - 1)
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX)) and bool(mallopt(_M_TRIM_THRESHOLD, keep))


def rss_kb() -> int:
    """This process's resident set size in kB (0 where ``/proc`` is absent)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * _PAGE_KB
    except (OSError, IndexError, ValueError):
        return 0


class HeapTrimmer:
    """Calls ``malloc_trim(0)`` and keeps count of what it gave back (for ``NodeStatus.extra``)."""

    def __init__(self) -> None:
        self._trim = _malloc_trim()
        self.trims = 0
        self.released_kb = 0

    @property
    def available(self) -> bool:
        return self._trim is not None

    def __call__(self) -> int:
        """Trim once; the kB of RSS it released (0 when nothing was free or trimming is unavailable)."""
        if self._trim is None:
            return 0
        before = rss_kb()
        self._trim(0)
        released = max(0, before - rss_kb())
        self.trims += 1
        self.released_kb += released
        return released
