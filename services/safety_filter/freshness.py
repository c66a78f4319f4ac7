"""Freshness of the map by its content, not by its arrival (DESIGN "What a stamp means").

An ESDF's ``header.stamp_ns`` is the time of the newest sensor data integrated into it; mapping
keeps it across re-publications (a risk-config change, a recentring), so a map re-emitted while
perception is dead still ages. With ``now`` the local wall clock, the map's *content age* is

.. math::  a = t_{now} - t_{stamp}

and a map is usable only while :math:`a \\le T + \\epsilon`, with :math:`T` the map timeout and
:math:`\\epsilon` the clock-offset tolerance between the machine that stamped the data and this
one (0 with chrony/PTP-synchronised clocks is ideal; the tolerance covers an unsynchronised
site). A stamp more than :math:`\\epsilon` in the future is equally unusable: that clock is wrong.
Arrival time remains the second check (``FilterSupervisor``): the content can be fresh and the
link dead.

On arrival a map is refused (the map in force is kept) when

- its content is already stale or from the future (``stale_map`` / ``future_map``);
- its publisher's ``seq`` did not increase (``seq_backwards``: a stuck or replayed publisher).
  The publisher is the Zenoh entity that put the sample (source info, set by every riskfield
  node); a new publisher, e.g. a restarted mapper whose seq starts again at 0, starts afresh.
  A sample without source info (a foreign client) is one anonymous publisher whose seq may
  restart only with newer content;
- its content is older than the map in force (``older_map``): a second publisher replaying old
  data alongside the live one never takes over.

Every publisher seen within ``window_s`` is counted: two at once on ``map/esdf`` is a fault the
status reports (``SafetyStatus.esdf_publishers``).

Only an admitted map records its publisher's ``seq``: a refused one (stale, from the future,
older) never moves it, or a forged map carrying a live publisher's source id and a huge ``seq``
would lock that publisher out for good while being refused itself.
"""

from __future__ import annotations

from dataclasses import dataclass, field

ANONYMOUS = ""  # the publisher of samples that carry no Zenoh source info
MAX_PUBLISHERS = 64  # bounded memory whatever a flood of forged publishers does


@dataclass
class _Publisher:
    seq: int | None  # the seq of its last admitted map (None: none admitted yet)
    seen: float  # local monotonic time of its last sample


@dataclass
class MapFreshness:
    """Admission and content age of maps; pure (every time is an argument)."""

    timeout_s: float = 0.3
    clock_tolerance_s: float = 0.1
    window_s: float = 2.0
    stamp_ns: int | None = None  # content stamp of the map in force
    refused: dict[str, int] = field(default_factory=dict)
    _publishers: dict[str, _Publisher] = field(default_factory=dict)

    def admit(self, stamp_ns: int, seq: int, publisher: str | None, now: float, wall_ns: int,
              commit: bool = True) -> str | None:
        """Whether a map may replace the one in force: None, or why it is refused (counted).
        With ``commit=False`` an admitted map is not yet the one in force: the caller calls
        ``commit`` once it proved usable, so an unusable map moves no seq or stamp either."""
        pid = publisher or ANONYMOUS
        reason = self._check(stamp_ns, seq, pid, wall_ns)
        prev = self._publishers.get(pid)
        if prev is None:
            prev = self._publishers[pid] = _Publisher(None, now)
        prev.seen = now
        self._prune(now)
        if reason is not None:
            self.refused[reason] = self.refused.get(reason, 0) + 1
            return reason
        if commit:
            self.commit(stamp_ns, seq, publisher)
        return None

    def commit(self, stamp_ns: int, seq: int, publisher: str | None) -> None:
        """The admitted map is the one in force: its stamp and its publisher's seq are recorded."""
        prev = self._publishers.get(publisher or ANONYMOUS)
        if prev is not None:
            prev.seq = seq
        self.stamp_ns = stamp_ns

    def _check(self, stamp_ns: int, seq: int, pid: str, wall_ns: int) -> str | None:
        age_s = (wall_ns - stamp_ns) * 1e-9
        if age_s > self.timeout_s + self.clock_tolerance_s:
            return "stale_map"
        if age_s < -self.clock_tolerance_s:
            return "future_map"
        prev = self._publishers.get(pid)
        newer = self.stamp_ns is None or stamp_ns > self.stamp_ns
        if prev is not None and prev.seq is not None and seq <= prev.seq and not (pid == ANONYMOUS and newer):
            return "seq_backwards"
        if self.stamp_ns is not None and stamp_ns < self.stamp_ns:
            return "older_map"
        return None

    def _prune(self, now: float) -> None:
        for pid in [p for p, v in self._publishers.items() if now - v.seen > self.window_s]:
            del self._publishers[pid]
        while len(self._publishers) > MAX_PUBLISHERS:
            del self._publishers[min(self._publishers, key=lambda p: self._publishers[p].seen)]

    def publishers(self, now: float) -> int:
        """How many distinct publishers put a map within the last ``window_s``."""
        return sum(now - v.seen <= self.window_s for v in self._publishers.values())

    def age_s(self, wall_ns: int) -> float | None:
        """Content age of the map in force (None before any)."""
        return None if self.stamp_ns is None else (wall_ns - self.stamp_ns) * 1e-9

    def stale(self, wall_ns: int) -> bool:
        age = self.age_s(wall_ns)
        return age is not None and (age > self.timeout_s + self.clock_tolerance_s or age < -self.clock_tolerance_s)

    @property
    def refused_total(self) -> int:
        return sum(self.refused.values())
