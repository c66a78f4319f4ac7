"""The cmd/ref arbitration core (runtime.arbiter): twist_mux's priorities, timeouts and locks."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from riskfield.services.runtime.arbiter import IDLE, LOCKED, PREEMPTED, UNKNOWN, CommandMux, MuxInput, MuxLock
from riskfield.services.safety_filter.settings import FilterSettings


def mux() -> CommandMux:
    return CommandMux([MuxInput("joystick", 100, 0.5), MuxInput("navigator", 10, 0.5)])


def test_the_joystick_outranks_the_navigator_until_its_claim_times_out():
    m = mux()
    assert m.admit("navigator", 0.0) is None and m.active(0.0) == "navigator"
    assert m.admit("joystick", 0.1) is None  # a higher priority takes over at once
    assert m.admit("navigator", 0.15) == PREEMPTED
    assert m.admit("joystick", 0.2, claims=False) is None  # the release: still the active source
    assert m.admit("navigator", 0.5) == PREEMPTED  # the claim of 0.1 holds 0.5 s
    assert m.admit("navigator", 0.61) is None and m.active(0.61) == "navigator"
    assert m.admit("joystick", 0.7, claims=False) == IDLE  # released: zeros do not take it back
    assert m.admit("joystick", 0.8) is None  # the dead-man again


def test_a_declining_source_alone_still_gives_a_reference():
    m = mux()
    assert m.admit("joystick", 0.0, claims=False) is None
    assert m.active(0.0) is None


def test_a_never_heard_source_holds_nothing_even_with_timeout_0():
    m = CommandMux([MuxInput("teleop", 100, 0.0), MuxInput("nav", 10, 0.5)])
    assert m.admit("nav", 5.0) is None


def test_undeclared_sources_take_the_default_or_are_refused():
    strict = mux()
    assert strict.admit("stranger", 0.0) == UNKNOWN
    assert strict.masked("stranger", 0.0)
    lenient = CommandMux([MuxInput("navigator", 10, 0.5)], default_input=(0, 0.5))
    assert lenient.admit("bench", 0.0) is None
    assert lenient.admit("navigator", 0.1) is None and lenient.admit("bench", 0.2) == PREEMPTED


def test_a_lock_holds_the_sources_below_it_and_only_its_source_releases_it():
    m = CommandMux([MuxInput("joystick", 100, 0.5), MuxInput("navigator", 10, 0.5)],
                   [MuxLock("pause", 50, 0.0)], default_lock=(255, 0.0))
    m.admit("navigator", 0.0)
    m.lock("pause", True, 0.1)
    assert m.admit("navigator", 0.2) == LOCKED and m.masked("navigator", 0.2) and m.active(0.2) is None
    assert m.admit("joystick", 0.3) is None  # above the pause lock: twist_mux's "same priority as joystick"
    m.lock("estop", True, 0.4)  # undeclared: the default lock, above everything
    assert m.admit("joystick", 0.5) == LOCKED and m.lock_priority(0.5) == 255
    m.lock("pause", False, 0.6)
    assert m.admit("joystick", 0.7) == LOCKED  # the e-stop's lock is its own
    m.lock("estop", False, 0.8)
    assert m.admit("joystick", 0.9) is None and m.lock_priority(0.9) == 0
    assert not CommandMux([]).lock("estop", True, 0.0)  # no default lock: ignored


def test_a_silent_lock_publisher_locks_with_a_timeout():
    m = CommandMux([MuxInput("joystick", 100, 0.5)], [MuxLock("heartbeat", 255, 0.3)])
    assert m.admit("joystick", 0.0) == LOCKED  # never heard: locked, as twist_mux's stamp 0
    m.lock("heartbeat", False, 0.1)
    assert m.admit("joystick", 0.2) is None
    assert m.admit("joystick", 0.45) == LOCKED  # 0.35 s of silence


def test_duplicates_are_refused():
    with pytest.raises(ValueError, match="twice"):
        CommandMux([MuxInput("a", 1, 0.5), MuxInput("a", 2, 0.5)])


def test_the_settings_describe_the_mux():
    m = FilterSettings().command_mux()
    assert m.inputs["joystick"].priority > m.inputs["navigator"].priority
    assert m.admit("bench", 0.0) is None  # undeclared sources: priority 0 by default
    assert FilterSettings(ref_default_priority=None).command_mux().admit("bench", 0.0) == UNKNOWN
    with pytest.raises(ValueError, match="priorty"):
        FilterSettings(ref_sources={"joystick": {"priorty": 3}})


# -- property: the forwarded source is the one twist_mux's rules name ---------------------------------
SOURCES = [("a", 30, 0.5), ("b", 20, 0.0), ("c", 20, 0.3), ("d", 5, 0.2)]
event = st.tuples(st.floats(0.0, 0.4), st.sampled_from(["a", "b", "c", "d", "lock", "unlock"]), st.booleans())


@given(st.lists(event, max_size=40), st.integers(0, 40))
def test_the_forwarded_source_is_the_highest_live_one_not_locked(events, lock_priority):
    m = CommandMux([MuxInput(*s) for s in SOURCES], [MuxLock("L", lock_priority, 0.0)])
    claims: dict[str, float] = {}
    locked = False
    now = 0.0
    for dt, who, claim in events:
        now += dt
        if who in ("lock", "unlock"):
            locked = who == "lock"
            m.lock("L", locked, now)
            continue
        if claim:
            claims[who] = now
        floor = lock_priority if locked else 0
        live = [(p, -i, n) for i, (n, p, t) in enumerate(SOURCES)
                if n in claims and (t == 0 or now - claims[n] <= t) and p >= floor]
        best = max(live)[2] if live else None
        forwarded = m.admit(who, now, claims=claim) is None
        priority = dict((n, p) for n, p, _ in SOURCES)[who]
        assert forwarded == (best == who or (best is None and not claim and priority >= floor))
        assert m.active(now) == best
