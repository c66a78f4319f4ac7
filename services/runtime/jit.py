"""numba where it is installed: the one optional import behind the compiled kernels.

The filter's compiled step (``fields.compiled``, ``safety_filter.compiled``) and the simulated
camera path's kernels (``perception.kernels``, ``simulator.kernels``) run compiled when numba is
there and fall back to their numpy reference paths (same results, tested) when an install left
it out (``pip install ".[robot]"`` on a platform without a numba wheel). Mapping needs numba and
imports it directly.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

numba: Any
njit: Any
try:
    import numba
    from numba import njit

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised on installs without numba
    numba = None
    njit = None
    HAVE_NUMBA = False

__all__ = ["HAVE_NUMBA", "njit", "numba", "threads"]


@contextmanager
def threads(n: int) -> Iterator[None]:
    """Run the compiled parallel loops (``prange``) called inside on ``n`` threads, capped at numba's
    pool; numba keeps the count per calling thread, so other threads' kernels are not affected.
    Without numba: nothing to set."""
    if numba is None:
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(before)
