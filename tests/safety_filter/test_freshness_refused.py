"""A refused or unusable map moves no publisher's seq and no content stamp (freshness, pure)."""

from __future__ import annotations

from riskfield.services.safety_filter.freshness import MapFreshness

S = 1_000_000_000
WALL = 1_800_000_000 * S
HUGE = 2**64 - 1


def test_a_refused_map_never_records_its_seq():
    f = MapFreshness(timeout_s=0.3, clock_tolerance_s=0.1)
    assert f.admit(WALL, 5, "mapper", 0.0, WALL) is None
    # forged with the mapper's source id: from the future, stale, older — all refused
    assert f.admit(WALL + 3600 * S, HUGE, "mapper", 0.01, WALL) == "future_map"
    assert f.admit(WALL - 10 * S, HUGE, "mapper", 0.02, WALL) == "stale_map"
    assert f.admit(WALL - 1, HUGE, "mapper", 0.03, WALL) == "older_map"
    assert f.admit(WALL + 1, 6, "mapper", 0.04, WALL) is None  # the live mapper goes on
    assert f.refused == {"future_map": 1, "stale_map": 1, "older_map": 1}
    # a publisher seen only through refused maps counts as seen, and its first good map is taken
    assert f.admit(WALL + 3600 * S, HUGE, "other", 0.05, WALL) == "future_map"
    assert f.publishers(0.05) == 2
    assert f.admit(WALL + 2, 0, "other", 0.06, WALL) is None


def test_an_admitted_map_is_in_force_only_once_committed():
    f = MapFreshness()
    assert f.admit(WALL, 5, "mapper", 0.0, WALL, commit=False) is None
    assert f.stamp_ns is None  # not yet usable (the caller validates it first)
    assert f.admit(WALL + 1, 6, "mapper", 0.01, WALL, commit=False) is None  # seq 5 was not recorded
    f.commit(WALL + 1, 6, "mapper")
    assert f.stamp_ns == WALL + 1
    assert f.admit(WALL + 2, 6, "mapper", 0.02, WALL) == "seq_backwards"
