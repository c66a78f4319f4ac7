"""``riskfield bench crowd --mode core``: the families' episodes are seeded and pure, the walker
plans read as the simulator reads them, the metrics count what they say on hand-made tracks, and
one short episode of every family runs in closed loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskfield.experiments import crowd_core as C
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter


def _trace(xy: np.ndarray, yaw: np.ndarray, v: np.ndarray, people: np.ndarray, v_ref: float) -> C.Trace:
    n = len(xy)
    dt = 1.0 / C.RATE_HZ
    return C.Trace(t=dt * np.arange(1, n + 1), xy=xy, yaw=yaw, velocity=v, omega=np.zeros(n),
                   v_ref=np.full(n, v_ref), w_ref=np.zeros(n), u=np.zeros((n, 2)), people=people,
                   yielding=np.zeros(n, bool), object_rows=np.zeros(n, int), fallbacks={},
                   start_xy=xy[0].copy(), start_yaw=float(yaw[0]))


@pytest.mark.parametrize("family", C.FAMILIES)
def test_the_generator_is_deterministic_per_seed(family):
    a, b, c = C.episode(family, 7), C.episode(family, 7), C.episode(family, 8)
    assert a.walkers == b.walkers and a.statics == b.statics and a.params == b.params
    assert a.duration_s == b.duration_s and a.v_ref == b.v_ref and a.sigma == b.sigma
    assert (a.walkers, a.statics, a.params) != (c.walkers, c.statics, c.params)


def test_plans_read_as_the_simulator_reads_them():
    from riskfield.services.simulator.scene import Motion

    for family in C.FAMILIES:
        for spec in C.episode(family, 3).walkers:
            m = Motion(np.asarray(spec["waypoints"]), spec["speed"], "once", waits=np.asarray(spec["waits"]))
            for t in np.linspace(0.0, 25.0, 60):
                pos, _, vel = m.state(np.asarray(spec["position"], float), 0.0, float(t))
                mine, v = C.plan_state(spec, float(t))
                assert np.allclose(mine, pos, atol=1e-9) and np.allclose(v, vel, atol=1e-9), (family, t)


def test_a_robot_driving_into_a_person_is_an_at_fault_contact():
    """The robot drives at 0.5 m/s into a person standing 0.5 m ahead of its centre, to 5 cm from them."""
    n = 100
    x = np.linspace(0.0, 0.45, n)
    xy = np.column_stack([x, np.zeros(n)])
    people = np.tile(np.array([[0.5, 0.0]]), (n, 1))[:, None, :]
    ep = C.Episode("groups", 0, 0.5, 2.0, 10.0, 0.15, [], [{}])
    m = C.episode_metrics(ep, _trace(xy, np.zeros(n), np.tile([0.5, 0.0], (n, 1)), people, 0.5))
    overlap = (0.5 - x) < C.HX + C.PERSON
    assert m["at_fault_contacts"] == int(overlap.sum()) > 0 and m["at_fault_episodes"] == 1
    assert m["person_contacts"] == 0 and m["min_separation_m"] == pytest.approx(-(C.HY + C.PERSON), abs=1e-9)
    assert m["success"] is False and m["blind_reverse_m"] == 0.0 and m["idle_displacement_m"] == 0.0


def test_a_standing_robot_has_no_idle_displacement_and_a_walked_into_one_is_the_persons_contact():
    n = 80
    xy, yaw = np.zeros((n, 2)), np.zeros(n)
    walk = np.column_stack([np.linspace(1.0, 0.2, n), np.zeros(n)])[:, None, :]
    ep = C.Episode("idle_passing", 0, 0.0, 2.0, None, 0.15, C.room_walls(), [{}])
    m = C.episode_metrics(ep, _trace(xy, yaw, np.zeros((n, 2)), walk, 0.0))
    assert m["idle_displacement_m"] == 0.0 and m["blind_reverse_m"] == 0.0 and m["time_stopped_s"] == 0.0
    assert m["person_contacts"] > 0 and m["at_fault_contacts"] == 0 and m["static_contacts"] == 0
    assert m["success"] is None and not m["reachable"]


def test_idle_displacement_reverse_freezing_and_static_contacts_are_measured():
    n = 50
    back = np.column_stack([np.linspace(0.0, -0.3, n), np.zeros(n)])  # reverses 0.3 m, unasked
    wall = C.box("w", "wall", -0.6, -1.0, -0.4, 1.0)  # the rear bumper reaches it at x = -0.239
    ep = C.Episode("wall_behind", 0, 0.0, 1.0, None, 0.15, [wall], [])
    m = C.episode_metrics(ep, _trace(back, np.zeros(n), np.tile([-0.3, 0.0], (n, 1)), np.zeros((n, 0, 2)), 0.0))
    assert m["idle_displacement_m"] == pytest.approx(0.3) and m["blind_reverse_m"] == pytest.approx(0.3)
    assert m["static_contacts"] == int((back[:, 0] - C.HX < -0.4).sum()) > 0 and m["static_episodes"] == 1
    still = C.episode_metrics(C.Episode("noise", 0, 0.5, 1.0, 3.0, 0.15, [], []),
                              _trace(np.zeros((n, 2)), np.zeros(n), np.zeros((n, 2)), np.zeros((n, 0, 2)), 0.5))
    assert still["time_stopped_s"] == pytest.approx(n / C.RATE_HZ) and still["idle_displacement_m"] == 0.0


def test_static_gap_of_a_rotated_rectangle_and_a_box():
    b = C.box("b", "cabinet", 1.0, -0.5, 2.0, 0.5)
    gap = C.static_gap(np.array([[0.0, 0.0], [1.5, 0.0], [0.5, 0.0]]), np.array([0.0, 0.3, math.pi / 2]), b)
    assert gap[0] == pytest.approx(1.0 - C.HX)
    assert gap[1] < -0.2  # inside: the smallest push out, across its 0.22 m width
    assert gap[2] == pytest.approx(0.5 - C.HY)  # turned: its side faces the box
    # A thin wall across the middle of the body, no corner of either inside the other.
    cross = C.static_gap(np.zeros((1, 2)), np.zeros(1), C.box("w", "wall", -0.02, -1.0, 0.02, 1.0))
    assert cross[0] < 0


def test_one_short_episode_per_family_runs():
    filt = SafetyFilter(FilterConfig())
    for family in C.FAMILIES:
        ep = C.episode(family, 0)
        tr = C.run_episode(ep, filt, max_s=4.0)
        m = C.episode_metrics(ep, tr)
        assert len(tr.t) == 200 and np.isfinite(tr.xy).all(), family
        assert m["idle_displacement_m"] == 0.0 or ep.v_ref > 0, family


def test_the_results_section_is_rewritten_between_its_markers(tmp_path):
    rows = [C.episode_metrics(ep, C.run_episode(ep, max_s=1.0)) for ep in [C.episode("runners", 0)]]
    summary = {"command": "riskfield bench crowd --mode core --episodes 1", "episodes_per_family": 1,
               "wall_time_s": 1.0, "sim_time_s": 1.0,
               "families": {"runners": C.summarise(rows, 1.0)}}
    path = tmp_path / "RESULTS.md"
    path.write_text("# Results\n\n## Other\n\nkept\n")
    C.update_results(path, summary)
    C.update_results(path, summary)
    text = path.read_text()
    assert text.count(C.RESULTS_BEGIN) == 1 and text.count("## Crowd families (core)") == 1
    assert "kept" in text and "| runners | 1 (0–0) |" in text
