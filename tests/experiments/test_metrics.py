"""The paper's metrics on tiny hand-made trajectories whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.experiments.metrics import (
    Rollout,
    matched,
    matched_end_index,
    mp_clearance,
    progress_curve,
    progress_to_goal,
    summarise,
)

S, G = np.array([0.0, 0.0]), np.array([4.0, 0.0])


def line(xs: list[float]) -> np.ndarray:
    return np.array([[x, 0.0] for x in xs])


def test_progress_is_normalised_distance_toward_goal():
    assert progress_to_goal(line([0, 1, 2]), S, G) == pytest.approx(0.5)
    assert progress_to_goal(line([0, 4]), S, G) == 1.0
    assert progress_to_goal(line([0, -1]), S, G) == 0.0  # moving away is clipped to 0
    assert progress_to_goal(np.array([[0.0, 0.0], [4.0, 3.0]]), S, G) == pytest.approx(0.25)  # 4 → 3 m away
    np.testing.assert_allclose(progress_curve(line([0, 1, 3, 2]), S, G), [0, 0.25, 0.75, 0.5])


def test_matched_end_index_is_first_crossing():
    curve = np.array([0.0, 0.2, 0.5, 0.4, 0.6])
    assert matched_end_index(curve, 0.5) == 2
    assert matched_end_index(curve, 0.0) == 0
    assert matched_end_index(curve, 0.6) == 4


def test_mp_clearance_ignores_what_comes_after_common_progress():
    # Clearance dips to −0.1 only after x = 3; with common progress 0.5 (x = 2) it is not counted.
    path = line([0, 1, 2, 3, 4])
    clearance = np.array([0.5, 0.3, 0.2, -0.1, 0.4])
    curve = progress_curve(path, S, G)
    assert mp_clearance(clearance, curve, 0.5) == pytest.approx(0.2)
    assert mp_clearance(clearance, curve, 1.0) == pytest.approx(-0.1)


def test_conservative_method_gets_no_clearance_bonus():
    """The paper's example: a method that stops early must be compared on the same stretch."""
    # Method A stops at x = 1 (progress 0.25) keeping 0.3 m; method B drives through a tight
    # spot at x = 3 (clearance 0.02) but at x ≤ 1 it had 0.25 m.
    a = Rollout("A", 0, "high", line([0, 0.5, 1, 1, 1]), S, G, np.array([0.5, 0.4, 0.3, 0.3, 0.3]))
    b = Rollout("B", 0, "high", line([0, 1, 2, 3, 4]), S, G, np.array([0.5, 0.25, 0.2, 0.02, 0.4]))
    mp = matched([a, b], ["A", "B"])
    assert mp[("A", 0)] == pytest.approx(0.3)
    assert mp[("B", 0)] == pytest.approx(0.25)  # only up to x = 1
    # Without matching B would look worse (0.02) than it is over the common part.
    assert b.clearance.min() == pytest.approx(0.02)


def test_collision_rate_counts_negative_mp_clearance():
    runs = []
    clearances = {0: [0.3, -0.05, 0.3], 1: [0.3, 0.1, 0.2], 2: [0.3, 0.2, -0.2], 3: [-0.01, 0.2, 0.3]}
    for pair, c in clearances.items():
        runs.append(Rollout("m", pair, "low" if pair < 2 else "high", line([0, 2, 4]), S, G, np.array(c),
                            filter_times=np.full(3, 1e-3)))
    mp = matched(runs, ["m"])  # one method: common progress = its own reach
    total = summarise(runs, mp, "m")
    assert total.n == 4
    assert total.mp_collision_rate == pytest.approx(3 / 4)
    assert total.mp_clearance_m == pytest.approx(np.mean([-0.05, 0.1, -0.2, -0.01]))
    assert total.progress == 1.0
    assert total.computation_time_s == pytest.approx(1e-3)
    low, high = summarise(runs, mp, "m", "low"), summarise(runs, mp, "m", "high")
    assert (low.n, low.mp_collision_rate) == (2, 0.5)
    assert (high.n, high.mp_collision_rate) == (2, 1.0)
    assert summarise(runs, mp, "m", "mid").n == 0


def test_matching_requires_every_method():
    a = Rollout("A", 0, "low", line([0, 1]), S, G, np.array([0.1, 0.1]))
    with pytest.raises(ValueError, match="no roll-out"):
        matched([a], ["A", "B"])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1, 5), min_size=2, max_size=30), st.lists(st.floats(-1, 5), min_size=2, max_size=30),
       st.integers(0, 2**31))
def test_mp_properties(xa, xb, seed):
    rng = np.random.default_rng(seed)
    pa, pb = line([0.0, *xa]), line([0.0, *xb])
    ca, cb = rng.uniform(-0.2, 0.5, len(pa)), rng.uniform(-0.2, 0.5, len(pb))
    a, b = Rollout("A", 0, "low", pa, S, G, ca), Rollout("B", 0, "low", pb, S, G, cb)
    mp = matched([a, b], ["A", "B"])
    # Matched clearance is never below the whole-path minimum and never above the start's.
    for r in (a, b):
        assert r.clearance.min() - 1e-12 <= mp[(r.method, 0)] <= r.clearance[0] + 1e-12
    # The method with the larger reach is evaluated on a prefix no longer than its own path;
    # the one with the smaller reach on its prefix up to its own maximum.
    low = a if a.reached <= b.reached else b
    assert mp[(low.method, 0)] == pytest.approx(low.clearance[: matched_end_index(low.curve, low.reached) + 1].min())


def test_full_run_metrics_count_collisions_after_the_matched_progress():
    """Worked by hand: method A dips to -0.05 m *after* the common progress, which the MP metrics
    forgive and the full-run metrics do not; B never collides."""
    start, goal = np.zeros(3), np.array([4.0, 0.0, 0.0])
    path_a = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])  # progress 0, .25, .5, .75
    path_b = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])  # reaches 0.5: the common progress
    a = Rollout("A", 0, "high", path_a, start, goal, np.array([0.3, 0.2, 0.1, -0.05]),
                np.full(3, 1e-4), relaxed_steps=1)
    b = Rollout("B", 0, "high", path_b, start, goal, np.array([0.3, 0.25, 0.2]), np.full(2, 1e-4))
    mp = matched([a, b], ("A", "B"))
    assert mp[("A", 0)] == 0.1 and mp[("B", 0)] == 0.2  # up to progress 0.5
    sa, sb = summarise([a, b], mp, "A"), summarise([a, b], mp, "B")
    assert sa.mp_collision_rate == 0.0 and sa.collision_rate == 1.0
    assert sa.min_clearance_m == -0.05 and sb.min_clearance_m == 0.2 and sb.collision_rate == 0.0
    assert sa.relaxed_fraction == 1 / 3 and sb.relaxed_fraction == 0.0
