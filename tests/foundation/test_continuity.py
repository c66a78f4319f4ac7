"""State admission by continuity (runtime.continuity) and the inbox's byte bound (runtime.inbox)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol.platforms import LIMO
from riskfield.services.runtime.continuity import FUTURE, JUMP, StateGate, StateGateSettings
from riskfield.services.runtime.inbox import ITEM_OVERHEAD, Inbox

S = 1_000_000_000
WALL = 1_800_000_000 * S


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.005, 0.5), st.floats(-math.pi, math.pi), st.floats(0.0, 1.0)),
                min_size=1, max_size=40))
def test_any_motion_within_the_platform_limits_is_admitted(steps):
    gate = StateGate()  # the LIMO's 1 m/s, 0.25 m of tolerance
    p, t, now = np.zeros(3), WALL, 0.0
    assert gate.admit(p, t, now, t) is None
    for dt, heading, speed in steps:
        p = p + LIMO.max_linear * speed * dt * np.array([math.cos(heading), math.sin(heading), 0.0])
        t += round(dt * S)
        now += dt
        assert gate.admit(p, t, now, t) is None
    assert gate.refused == {}


@settings(max_examples=60, deadline=None)
@given(st.floats(0.001, 2.0), st.floats(-math.pi, math.pi), st.floats(1.01, 1000.0))
def test_a_jump_beyond_speed_times_dt_plus_tolerance_is_refused_and_keeps_the_reference(dt, heading, factor):
    gate = StateGate(max_speed=1.0, tolerance_m=0.25)
    assert gate.admit((0.0, 0.0, 0.0), WALL, 0.0, WALL) is None
    far = factor * (1.0 * dt + 0.25) * np.array([math.cos(heading), math.sin(heading), 0.0])
    t = WALL + round(dt * S)
    assert gate.admit(far, t, dt, t) == JUMP
    # the reference did not move: a sample next to the old position is still admitted
    assert gate.admit((0.01, 0.0, 0.0), t, dt, t) is None
    assert gate.refused == {JUMP: 1}


def test_dt_is_the_larger_of_the_stamps_and_the_arrivals():
    gate = StateGate(max_speed=1.0, tolerance_m=0.1)
    gate.admit((0.0, 0.0, 0.0), WALL, 0.0, WALL)
    # a burst after a stall: stamped 1 s apart, arriving together → the stamps' dt counts
    assert gate.admit((1.0, 0.0, 0.0), WALL + S, 0.0, WALL + S) is None
    # an unstamped-looking (old) stamp arriving 1 s later → the arrivals' dt counts
    assert gate.admit((2.0, 0.0, 0.0), WALL, 1.0, WALL + 2 * S) is None
    assert gate.admit((9.0, 0.0, 0.0), WALL, 1.0, WALL + 2 * S) == JUMP


def test_relocalise_takes_any_jump_and_future_stamps_are_refused():
    gate = StateGate(clock_tolerance_s=0.1)
    gate.admit((0.0, 0.0, 0.0), WALL, 0.0, WALL)
    assert gate.admit((50.0, 0.0, 0.0), WALL, 0.0, WALL) == JUMP
    assert gate.relocalise((50.0, 0.0, 0.0), WALL, 0.0, WALL) is None
    assert gate.admit((50.05, 0.0, 0.0), WALL, 0.01, WALL) is None  # the new reference
    assert gate.admit((50.0, 0.0, 0.0), WALL + int(0.2 * S), 0.02, WALL) == FUTURE
    assert gate.relocalise((0.0, 0.0, 0.0), WALL + int(0.2 * S), 0.02, WALL) == FUTURE
    assert gate.admit((50.0, 0.0, 0.0), WALL + int(0.05 * S), 0.02, WALL) is None  # within the tolerance
    assert gate.admit((float("nan"), 0.0, 0.0), WALL, 0.03, WALL) == JUMP
    assert gate.refused == {JUMP: 2, FUTURE: 2} and gate.refused_total == 4


def test_gate_settings_default_to_the_platform():
    s = StateGateSettings()
    assert s.state_max_speed == LIMO.max_linear
    gate = StateGate.of(s, 0.3)
    assert (gate.max_speed, gate.tolerance_m, gate.clock_tolerance_s) == (LIMO.max_linear, 0.25, 0.3)


# -- the inbox's byte bound ----------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 5000), min_size=1, max_size=60), st.integers(ITEM_OVERHEAD, 20000))
def test_a_byte_bounded_fifo_never_holds_more_than_its_bytes_and_counts_every_drop(sizes, bound):
    inbox = Inbox()
    slot = inbox.slot("f", "fifo", maxlen=10**9, max_bytes=bound)
    for i, size in enumerate(sizes):
        inbox.put(slot, i, size)
        assert slot.nbytes <= bound
        assert slot.nbytes == sum(cost for _, cost in slot.items)
    got = []
    while (item := inbox.get(0)) is not None:
        got.append(item[1])
    assert got == sorted(got)  # order kept; the oldest went first
    assert slot.received == len(sizes) and slot.dropped == len(sizes) - len(got) and slot.nbytes == 0
    if sizes[-1] + ITEM_OVERHEAD <= bound:
        assert got[-1] == len(sizes) - 1  # the newest is always kept when it fits at all


def test_byte_bound_drops_the_oldest_and_an_item_over_the_bound_alone():
    inbox = Inbox()
    slot = inbox.slot("f", "fifo", maxlen=10**9, max_bytes=3 * (1000 + ITEM_OVERHEAD))
    for i in range(5):
        inbox.put(slot, i, 1000)
    inbox.put(slot, "huge", 10**6)
    assert [inbox.get(0)[1] for _ in range(3)] == [2, 3, 4]
    assert slot.dropped == 3 and inbox.get(0) is None
