"""Timing statistics, one naming for every bench and report: ``n``, ``median``, ``p90``, ``p95``,
``p99``, ``mean`` and ``max`` of a list of durations, in the unit they were measured in (the
caller's key or column says which: ``step_us``, ``"median ms"``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def timing_stats(samples: Sequence[float] | np.ndarray) -> dict[str, float] | None:
    """The summary of ``samples``; None when there are none (nothing measured is not a zero)."""
    a = np.asarray(samples, dtype=float)
    if a.size == 0:
        return None
    p50, p90, p95, p99 = (float(v) for v in np.percentile(a, [50, 90, 95, 99]))
    return {"n": int(a.size), "median": p50, "p90": p90, "p95": p95, "p99": p99, "mean": float(a.mean()),
            "max": float(a.max())}
