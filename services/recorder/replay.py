"""Replay schedule: when each record is due, from its log time, a speed factor and a remap."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from .mcap_io import Record


@dataclass(frozen=True)
class Remap:
    """Rewrites ``{old_root}/...`` keys to ``{new_root}/...`` (another robot id or prefix)."""

    old_root: str | None = None
    new_root: str | None = None

    def __call__(self, key: str) -> str:
        if self.old_root and self.new_root and key.startswith(self.old_root + "/"):
            return self.new_root + key[len(self.old_root):]
        return key


def schedule(records: Iterable[Record], speed: float = 1.0) -> Iterator[tuple[float, Record]]:
    """(seconds after the start at which to publish, record), keeping the recorded spacing / speed."""
    if speed <= 0:
        raise ValueError("speed must be > 0")
    t0 = None
    for rec in records:
        if t0 is None:
            t0 = rec.log_time_ns
        yield (rec.log_time_ns - t0) / 1e9 / speed, rec
