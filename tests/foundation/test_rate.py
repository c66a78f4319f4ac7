"""The token bucket (runtime/rate.py): an average-rate cap without phase locking."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.services.runtime.rate import TokenBucket


@settings(max_examples=200, deadline=None)
@given(rate=st.floats(1.0, 100.0), burst=st.floats(1.0, 4.0),
       gaps=st.lists(st.floats(0.0, 0.5), min_size=1, max_size=200))
def test_never_more_than_rate_times_t_plus_burst_in_any_interval(rate: float, burst: float, gaps: list[float]) -> None:
    bucket = TokenBucket(rate, burst)
    t = np.cumsum(gaps)
    passed = np.array([x for x in t if bucket.allow(float(x))])
    for i, start in enumerate(passed):
        n = passed[i:] - start  # events from this one on
        for j in range(len(n)):
            assert j + 1 <= rate * n[j] + burst + 1e-9


@settings(max_examples=100, deadline=None)
@given(rate=st.floats(1.0, 100.0), jitter=st.lists(st.floats(-0.3, 0.3), min_size=2, max_size=100))
def test_a_jittered_stream_at_the_cap_passes_whole(rate: float, jitter: list[float]) -> None:
    """Events at the capped rate, each up to 30 % of a period early or late:
    with a burst of 2 every one passes, where a min-interval cap would refuse the early ones."""
    period = 1.0 / rate
    t = [(k + j) * period for k, j in enumerate(jitter)]
    bucket = TokenBucket(rate, burst=2.0)
    assert all(bucket.allow(x) for x in t)


def test_a_faster_stream_is_thinned_to_the_rate() -> None:
    bucket = TokenBucket(10.0, burst=2.0)
    passed = sum(bucket.allow(k / 100.0) for k in range(1000))  # 100 Hz for 10 s
    assert 100 <= passed <= 102


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ValueError):
        TokenBucket(0.0)
    with pytest.raises(ValueError):
        TokenBucket(10.0, burst=0.5)
