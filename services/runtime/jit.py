"""What a node does about its compiled kernels: says while numba compiles (:func:`watch_compiles`),
runs their parallel loops on a thread count (:func:`threads`), and stops with the install hint where
a kernel that runs only compiled meets an install without numba (:func:`require_numba`). numba's
optional import and the kernels' decorator are ``protocol.kernels`` (:func:`jit`).

The simulated camera path (``perception.kernels``, ``simulator.kernels``) and the filter's
compiled step (``safety_filter.compiled``) run only compiled: where their kernels are built
without numba, a ``ModuleNotFoundError`` for ``numba`` (:func:`require_numba`) stops the node at
start with the runtime's one-line install hint (``service.missing_extra``). The extras that run
them (``robot``, ``mapping``, ``sim``) install it.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from riskfield.protocol.kernels import HAVE_NUMBA, jit, numba

__all__ = ["HAVE_NUMBA", "CompileWatch", "jit", "kernels", "numba", "require_numba", "threads", "watch_compiles"]


def require_numba(what: str) -> None:
    """Raise ``ModuleNotFoundError`` (``name="numba"``) when numba is not installed: ``what`` runs
    in compiled kernels only, and the runtime turns the error into its install hint."""
    if not HAVE_NUMBA:
        raise ModuleNotFoundError(f"No module named 'numba' ({what} runs compiled kernels only)", name="numba")

#: The logger (and log-line name) of compile progress; ``COMPILING`` starts each such line, which
#: is what a launcher reading a node's output looks for (``processes.Child.compiling``).
LOGGER = "kernels"
_VIEWS = "riskfield.protocol.kernels"
COMPILING = "compiling kernel"


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


def kernels() -> list[Any]:
    """The numba dispatchers (``@njit`` functions) defined by the riskfield modules loaded now."""
    if not HAVE_NUMBA or "numba" not in sys.modules:  # never import numba to find nothing compiled
        return []
    from numba.core.dispatcher import Dispatcher

    found: dict[int, Any] = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("riskfield.") or module is None:
            continue
        for value in list(vars(module).values()):
            if isinstance(value, Dispatcher) and getattr(value.py_func, "__module__", None) == name:
                found[id(value)] = value
    return list(found.values())


def kernel_name(dispatcher: Any) -> str:
    """``mapping.esdf_kernels.sweep`` for a dispatcher of ``riskfield.services.mapping.esdf_kernels``."""
    fn = getattr(dispatcher, "py_func", None)
    module = (getattr(fn, "__module__", None) or "?").removeprefix("riskfield.").removeprefix("services.")
    return f"{module}.{getattr(fn, '__qualname__', None) or repr(fn)}"


def cache_misses() -> int:
    """Signatures the loaded riskfield kernels compiled in this process because numba's on-disk cache
    did not have them (numba/core/dispatcher.py, ``Dispatcher.compile``: ``_cache_misses``)."""
    return sum(sum(d.stats.cache_misses.values()) for d in kernels())


class CompileWatch:
    """Logs every riskfield kernel numba compiles in this process (a cache miss: a cached one is
    loaded silently) with which kernel, how many so far of how many are loaded, and the time spent;
    counts them (signatures) for the node's status. One per process (:func:`watch_compiles`).

    numba broadcasts ``numba:compile`` around each compilation only, after its cache lookup missed
    (numba/core/dispatcher.py, ``Dispatcher.compile``; numba/core/event.py, ``register``). A kernel
    calling another one compiles the callee inside the caller's event: both are counted.
    """

    def __init__(self, log: logging.Logger | None = None):
        self.log = log or logging.getLogger(LOGGER)
        self.compiled = 0
        self.seconds = 0.0
        self._names: set[str] = set()
        self._open: list[tuple[str, float, bool]] = []  # (kernel, start, ours) of compilations in progress
        self._first: float | None = None
        self._lock = threading.Lock()

    def current(self) -> tuple[str, float] | None:
        """(kernel, seconds) of the outermost riskfield kernel being compiled, or None."""
        with self._lock:
            ours = [(name, t0) for name, t0, o in self._open if o]
        return (ours[0][0], time.monotonic() - ours[0][1]) if ours else None

    def _start(self, dispatcher: Any) -> None:
        ours = (getattr(getattr(dispatcher, "py_func", None), "__module__", None) or "").startswith("riskfield.")
        name = kernel_name(dispatcher)
        now = time.monotonic()
        with self._lock:
            self._open.append((name, now, ours))
            if not ours:  # numba's own helpers, compiled inside one of ours (and cached with it)
                return
            first = self._first is None
            if first:
                self._first = now
            self.compiled += 1
            self._names.add(name)
            n = len(self._names)
        if first:
            self.log.info("numba's cache has no %s for this process: compiling (once; `riskfield warmup` "
                          "does it ahead of start)", name)
        # Of the kernels loaded now: those compiled plus those not called yet (more modules may load),
        # but for the workspace views, which compile only inside the kernels that carve with them.
        pending = sum(1 for d in kernels() if not d.overloads and kernel_name(d) not in self._names
                      and d.py_func.__module__ != _VIEWS)
        self.log.info("%s %s (%d of %d, %.1f s so far)", COMPILING, name, n, n + pending, now - self._first)

    def _end(self) -> None:
        with self._lock:
            if not self._open:
                return
            name, t0, ours = self._open.pop()
            took = time.monotonic() - t0
            if ours and not any(o for _, _, o in self._open):
                self.seconds += took
        if ours:
            self.log.debug("compiled kernel %s in %.1f s", name, took)


_WATCH: CompileWatch | None = None


def watch_compiles() -> CompileWatch | None:
    """The process's :class:`CompileWatch`, registered with numba on first call; None when numba is
    not loaded (a node without kernels must not pay numba's import for this)."""
    global _WATCH
    if not HAVE_NUMBA or "numba" not in sys.modules:
        return None
    if _WATCH is None:
        from numba.core import event

        watch = CompileWatch()

        class _Listener(event.Listener):
            # Runs inside numba's compilation: a failure here must never fail the compile.
            def on_start(self, ev: Any) -> None:
                try:
                    watch._start((ev.data or {}).get("dispatcher"))
                except Exception:
                    watch.log.debug("compile event not understood: %r", ev, exc_info=True)

            def on_end(self, ev: Any) -> None:
                try:
                    watch._end()
                except Exception:
                    watch.log.debug("compile event not understood: %r", ev, exc_info=True)

        event.register("numba:compile", _Listener())
        _WATCH = watch
    return _WATCH


if HAVE_NUMBA:  # kernel modules import this one before any kernel runs: compiles are seen from the first
    watch_compiles()
