"""Map freshness by content: admission of maps and the content age, explicit clocks."""

from __future__ import annotations

import pytest

from riskfield.protocol import Header
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.freshness import MapFreshness
from riskfield.services.safety_filter.supervisor import FilterSupervisor

from .test_supervisor import grid, ref, state

S = 1_000_000_000  # ns per second
WALL = 1_800_000_000 * S  # some wall-clock instant


def stamped(stamp_ns: int, seq: int = 0):
    g = grid()
    g.header = Header(stamp_ns=stamp_ns, seq=seq)
    return g


def test_content_older_than_timeout_plus_tolerance_or_from_the_future_is_refused():
    f = MapFreshness(timeout_s=0.3, clock_tolerance_s=0.2)
    assert f.admit(WALL - int(0.49 * S), 0, "a", 0.0, WALL) is None
    assert f.admit(WALL - int(0.51 * S), 1, "a", 0.0, WALL) == "stale_map"
    assert f.admit(WALL + int(0.21 * S), 2, "a", 0.0, WALL) == "future_map"
    assert f.refused == {"stale_map": 1, "future_map": 1}
    assert f.stamp_ns == WALL - int(0.49 * S)  # the refused maps did not replace it


def test_seq_backwards_from_one_publisher_is_refused_and_a_new_publisher_starts_afresh():
    f = MapFreshness()
    assert f.admit(WALL, 5, "mapper-1", 0.0, WALL) is None
    assert f.admit(WALL + 1, 5, "mapper-1", 0.01, WALL) == "seq_backwards"  # stuck: the same seq again
    assert f.admit(WALL + 2, 3, "mapper-1", 0.02, WALL) == "seq_backwards"  # replayed
    assert f.admit(WALL + 3, 6, "mapper-1", 0.03, WALL) is None
    # the mapper restarts: a new Zenoh publisher whose seq starts at 0
    assert f.admit(WALL + 4, 0, "mapper-2", 0.04, WALL) is None
    assert f.refused == {"seq_backwards": 2}


def test_an_anonymous_publisher_may_restart_only_with_newer_content():
    f = MapFreshness()
    assert f.admit(WALL, 0, None, 0.0, WALL) is None
    assert f.admit(WALL, 0, None, 0.1, WALL) == "seq_backwards"
    assert f.admit(WALL + 1, 0, None, 0.2, WALL) is None


def test_content_older_than_the_map_in_force_is_refused_and_two_publishers_are_counted():
    f = MapFreshness(timeout_s=0.3, window_s=2.0)
    assert f.admit(WALL, 0, "live", 0.0, WALL) is None
    assert f.admit(WALL - int(0.1 * S), 0, "stuck", 0.05, WALL) == "older_map"
    assert f.publishers(0.1) == 2
    assert f.admit(WALL + 1, 1, "live", 2.5, WALL) is None
    assert f.publishers(2.5) == 1  # the stuck one went quiet


def test_the_publisher_table_is_bounded():
    f = MapFreshness()
    for i in range(1000):
        f.admit(WALL + i, 0, f"p{i}", 0.0, WALL + i)
    assert f.publishers(0.0) <= 64


def make() -> FilterSupervisor:
    return FilterSupervisor(SafetyFilter(FilterConfig()), 0.3, 0.3, 0.2, clock_tolerance_s=0.2)


def test_a_re_emitted_map_goes_stale_by_content_although_it_keeps_arriving():
    """The map arrives every 50 ms (mapping re-emits it on risk changes), but its content is the
    same old frame's: the filter brakes with stale_map and reports the content age."""
    sup = make()
    t, wall = 100.0, WALL
    frame_stamp = wall
    sup.on_state(state(), t)
    sup.on_ref(ref(), t)
    seq = 0
    fallbacks = []
    for _ in range(20):  # one second of re-emits of the same content
        g = stamped(frame_stamp, seq)
        if sup.admit_map(g, t, wall, "mapper") is None:
            sup.on_map(g, t)
        sup.on_state(state(), t)
        sup.on_ref(ref(), t)
        _, st = sup.tick(t, wall)
        fallbacks.append((round((wall - frame_stamp) / 1e6), st.fallback, st.esdf_age_ms))
        t, wall, seq = t + 0.05, wall + 50_000_000, seq + 1
    ok = [age for age, fb, _ in fallbacks if fb is None]
    stale = [(age, reported) for age, fb, reported in fallbacks if fb == "stale_map"]
    assert ok and max(ok) <= 500 and stale and min(a for a, _ in stale) > 500
    assert all(reported == pytest.approx(age) for age, reported in stale)  # the content age, not 0


def test_without_a_wall_clock_the_supervisor_keeps_its_arrival_checks():
    sup = make()
    sup.on_map(stamped(1), 0.0)  # a stamp from 1970: irrelevant without wall_ns
    sup.on_state(state(), 0.0)
    sup.on_ref(ref(), 0.0)
    _, st = sup.tick(0.01)
    assert st.fallback is None and st.esdf_age_ms == pytest.approx(10.0)


def test_a_steps_command_and_status_carry_the_wall_clock_it_judged_freshness_by():
    """So a receiver can check the content-age rule on stamps alone: a moving command's stamp is
    within timeout + tolerance of the newest map stamp, a brake's is past it."""
    sup = make()
    g = stamped(WALL)
    assert sup.admit_map(g, 0.0, WALL, "mapper") is None
    sup.on_map(g, 0.0)
    sup.on_state(state(), 0.0)
    sup.on_ref(ref(), 0.0)
    moving_at = WALL + int(0.1 * S)
    cmd, st = sup.tick(0.1, moving_at)
    assert st.fallback is None and any(cmd.linear)
    assert cmd.header.stamp_ns == st.header.stamp_ns == moving_at
    sup.on_state(state(), 0.25)
    sup.on_ref(ref(), 0.25)
    braking_at = WALL + int(0.55 * S)  # content 0.55 s old: past 0.3 + 0.2, while it arrived 0.25 s ago
    cmd, st = sup.tick(0.25, braking_at)
    assert st.fallback == "stale_map" and not any(cmd.linear)
    assert cmd.header.stamp_ns == st.header.stamp_ns == braking_at
