r"""A token bucket: an average-rate cap that does not lock onto a timer's phase.

A cap of "at most one every :math:`1/r` s since the last" refuses an event that comes a little
early (jitter upstream) and defers it to whatever fires next, typically a node timer; from then
on the events follow that timer's phase, each late by up to a timer period: with a 10 Hz camera
and a 10 Hz ESDF cap (``MappingSettings.esdf_rate_hz``) about a third of the frames would reach no
ESDF.

The bucket holds up to :math:`b` tokens and refills at :math:`r` per second; an event is allowed
when it can take a whole token. Over any interval of length :math:`T` at most :math:`rT + b`
events pass, so the average rate stays capped, while an event up to :math:`(b - 1)/r` s early
still passes at once. Starting full, a stream at the rate whose events come up to
:math:`(b - 1)/2` periods early or late passes whole: between refills that hit the cap the
tokens before event :math:`k` are :math:`b - j_m + j_k \ge 1` (:math:`j` the lateness in periods,
:math:`m` the last event that found the bucket full).
"""

from __future__ import annotations


class TokenBucket:
    """``allow(now)``: take a token if one is there. Pure (the time is an argument)."""

    def __init__(self, rate_hz: float, burst: float = 2.0):
        if not rate_hz > 0 or not burst >= 1:
            raise ValueError(f"token bucket needs rate_hz > 0 and burst >= 1, got {rate_hz}, {burst}")
        self.rate_hz = rate_hz
        self.burst = burst
        self._tokens = burst
        self._t: float | None = None

    def allow(self, now: float) -> bool:
        if self._t is not None:
            self._tokens = min(self.burst, self._tokens + max(0.0, now - self._t) * self.rate_hz)
        self._t = now
        if self._tokens >= 1.0 - 1e-9:  # a refill of exactly one period is a whole token
            self._tokens -= 1.0
            return True
        return False
