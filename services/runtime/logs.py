"""Logging set-up and a rate limiter so a flood of bad input costs one line per period."""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections.abc import Callable


def setup_logging(service: str, level: str = "INFO") -> logging.Logger:
    root = logging.getLogger()
    if not any(getattr(h, "_riskfield", False) for h in root.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s", "%H:%M:%S"))
        handler._riskfield = True  # type: ignore[attr-defined]
        root.addHandler(handler)
    root.setLevel(level.upper())
    return logging.getLogger(service)


class RateLimitedLog:
    """At most one line per ``period_s`` for each topic, telling how many were suppressed."""

    def __init__(self, logger: logging.Logger, period_s: float = 2.0):
        self._log = logger
        self._period = period_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def __call__(self, level: int, topic: str, message: str, *, exc_info: bool = False) -> bool:
        now = time.monotonic()
        last = self._last.get(topic)
        if last is not None and now - last < self._period:
            self._suppressed[topic] = self._suppressed.get(topic, 0) + 1
            return False
        n = self._suppressed.pop(topic, 0)
        self._last[topic] = now
        suffix = f" ({n} more like it suppressed)" if n else ""
        self._log.log(level, "%s%s", message, suffix, exc_info=exc_info)
        return True


def process_age_s() -> float:
    """Seconds since this process was spawned (Linux: its start time in ``/proc/self/stat``, field 22,
    in clock ticks since boot, against ``/proc/uptime``); since this module loaded elsewhere."""
    try:
        with open("/proc/self/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return max(0.0, uptime - int(fields[19]) / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return time.monotonic() - _LOADED


_LOADED = time.monotonic()


def where(thread_id: int) -> str:
    """``mapping.mapper.Mapper.warm_up:182``: the innermost riskfield function a thread is in now
    (what a start-up that takes long is doing), or ``""``."""
    frame = sys._current_frames().get(thread_id)
    while frame is not None:
        module = frame.f_globals.get("__name__", "")
        if module.startswith("riskfield."):
            name = module.removeprefix("riskfield.").removeprefix("services.")
            return f"{name}.{frame.f_code.co_qualname}:{frame.f_lineno}"
        frame = frame.f_back
    return ""


class StartupReport:
    """While a node starts (session, then its service's setup), says every ``period_s`` what it is
    doing: the kernel numba is compiling, else where the start-up thread is. A context manager
    around the start-up; a thread of its own, stopped on exit."""

    def __init__(self, log: logging.Logger, period_s: float = 5.0, compiling: Callable[[], str] | None = None):
        self.log, self.period_s, self._compiling = log, period_s, compiling
        self._thread_id = threading.get_ident()
        self._done = threading.Event()
        self._t0 = time.monotonic()
        self._reporter = threading.Thread(target=self._report, name="startup-report", daemon=True)

    def __enter__(self) -> StartupReport:
        self._reporter.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._reporter.join()

    def _report(self) -> None:
        while not self._done.wait(self.period_s):
            doing = (self._compiling() if self._compiling else "") or where(self._thread_id) or "starting"
            self.log.info("still starting after %.0f s: %s", time.monotonic() - self._t0, doing)
