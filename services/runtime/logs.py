"""Logging set-up and a rate limiter so a flood of bad input costs one line per period."""

from __future__ import annotations

import logging
import sys
import time


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
