"""``riskfield bench crowd``: the people metrics (contact geometry, fault, ghost time, map lag), the
crowd cases (each a fair conflict) and the bench's bookkeeping; a 2-case run of the full stack is
``slow``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from riskfield.experiments import people as P
from riskfield.experiments.benches import crowd as bench
from riskfield.experiments.scenarios import (
    CROWD_KINDS,
    CROWD_SPEEDS,
    crowd_case,
    crowd_cases,
    crowd_nominal,
)
from riskfield.protocol import EsdfGrid, Header, RobotState, SafetyStatus, SimActor, SimActors, VelocityCommand, ade20k
from riskfield.services.safety_filter.config import LIMO_LENGTH, LIMO_WIDTH

xy = st.floats(-3.0, 3.0, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)


def _brute_gap(rx: float, ry: float, yaw: float, cx: float, cy: float, r: float) -> float:
    """Distance from the centre to a dense sampling of the rectangle (boundary for the inside depth)."""
    hx, hy = LIMO_LENGTH / 2, LIMO_WIDTH / 2
    c, s = math.cos(yaw), math.sin(yaw)
    qx, qy = c * (cx - rx) + s * (cy - ry), -s * (cx - rx) + c * (cy - ry)
    u = np.linspace(-1, 1, 2001)
    one = np.ones_like(u)
    edge = np.concatenate([np.column_stack([u * hx, one * hy]), np.column_stack([u * hx, -one * hy]),
                           np.column_stack([one * hx, u * hy]), np.column_stack([-one * hx, u * hy])])
    d = float(np.min(np.hypot(edge[:, 0] - qx, edge[:, 1] - qy)))
    inside = abs(qx) <= hx and abs(qy) <= hy
    return (-d if inside else d) - r


@settings(max_examples=200, deadline=None)
@given(rx=xy, ry=xy, yaw=angle, cx=xy, cy=xy, r=st.floats(0.0, 0.5))
def test_rectangle_gap_is_the_distance_from_the_limo_rectangle_to_the_cylinder(rx, ry, yaw, cx, cy, r):
    gap, point = P.rectangle_gap(np.array([[rx, ry]]), np.array([yaw]), np.array([[cx, cy]]), r)
    assert gap[0] == pytest.approx(_brute_gap(rx, ry, yaw, cx, cy, r), abs=1e-3)
    q = P.body_frame(np.array([[rx, ry]]), np.array([yaw]), point)[0]
    assert abs(q[0]) <= LIMO_LENGTH / 2 + 1e-9 and abs(q[1]) <= LIMO_WIDTH / 2 + 1e-9  # on the body
    if gap[0] + r > 1e-6:  # outside: the nearest point is at the gap's distance
        assert float(np.hypot(*(point[0] - (cx, cy)))) == pytest.approx(gap[0] + r, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(rx=xy, ry=xy, yaw=angle, cx=xy, cy=xy, vx=st.floats(-1, 1), vy=st.floats(-1, 1), w=st.floats(-2, 2))
def test_approach_speed_is_how_fast_the_gap_closes(rx, ry, yaw, cx, cy, vx, vy, w):
    """Outside the body, the gap's rate of change is minus the nearest point's approach speed (the
    nearest point is unique there, so the gap is differentiable in the pose)."""
    robot, centre = np.array([[rx, ry]]), np.array([[cx, cy]])
    gap, point = P.rectangle_gap(robot, np.array([yaw]), centre, 0.0)
    assume(gap[0] > 0.05)
    q = P.body_frame(robot, np.array([yaw]), centre)[0]
    # keep away from the corners' switching lines, where the nearest feature changes
    assume(min(abs(abs(q[0]) - LIMO_LENGTH / 2), abs(abs(q[1]) - LIMO_WIDTH / 2)) > 0.02)
    dt = 1e-5
    later, _ = P.rectangle_gap(robot + dt * np.array([[vx, vy]]), np.array([yaw + w * dt]), centre, 0.0)
    speed = P.approach_speed(robot, np.array([[vx, vy]]), np.array([w]), point, centre)
    assert -(later[0] - gap[0]) / dt == pytest.approx(speed[0], abs=2e-3)


def test_contacts_are_the_robots_when_it_moves_towards_the_person_else_the_persons():
    gap = np.array([0.2, 0.01, -0.01, -0.02, -0.02, 0.01, -0.01, -0.01, 0.3])
    approach = np.array([0.5, 0.5, 0.4, 0.06, 0.05, 0.0, 0.0, -0.2, -0.2])
    c = P.contacts(gap, approach)
    assert (c.at_fault_samples, c.at_fault_episodes) == (2, 1)
    assert (c.person_samples, c.person_episodes) == (3, 2)
    assert c.max_at_fault_speed == pytest.approx(0.4)


def test_a_robot_driving_into_a_standing_person_is_at_fault_and_one_walked_into_is_not():
    t = np.arange(0, 4, 0.02)
    x = np.minimum(-1.0 + 0.5 * t, 0.0)  # drives at 0.5 m/s into a person at (0.3, 0), until it stands at 0
    robot = np.column_stack([x, np.zeros_like(t)])
    vel = np.column_stack([np.where(x < 0, 0.5, 0.0), np.zeros_like(t)])
    person = np.tile([0.3, 0.0], (len(t), 1))
    gap, point = P.rectangle_gap(robot, np.zeros(len(t)), person, 0.22)
    c = P.contacts(gap, P.approach_speed(robot, vel, np.zeros(len(t)), point, person))
    assert c.at_fault_samples > 0 and c.max_at_fault_speed == pytest.approx(0.5)
    # the same overlap with the robot standing still and the person walking in: the person's
    walker = np.column_stack([np.maximum(1.0 - 0.5 * t, 0.2), np.zeros_like(t)])  # walks into its nose, stays
    still = np.zeros((len(t), 2))
    gap, point = P.rectangle_gap(still, np.zeros(len(t)), walker, 0.22)
    c = P.contacts(gap, P.approach_speed(still, np.zeros((len(t), 2)), np.zeros(len(t)), point, walker))
    assert c.at_fault_samples == 0 and c.person_samples > 0
    # backing away while the person closes in: still the person's
    c = P.contacts(gap, P.approach_speed(still, np.tile([-0.2, 0.0], (len(t), 1)), np.zeros(len(t)), point, walker))
    assert c.at_fault_samples == 0 and c.person_samples > 0


def test_ghost_time_is_the_hold_after_people_leave():
    t = np.arange(0, 10, 0.1)
    rel = t < 2.0  # a person in the way until 2 s
    ratio = np.where(t < 3.5, 0.0, 1.0)  # the command recovers at 3.5 s
    valid = np.ones(len(t), bool)
    g = P.ghost_time(t, ratio, valid, rel)
    assert g.time_s == pytest.approx(1.5, abs=0.11) and not g.censored
    # a fail-safe brake in the middle is not the map's ghost
    g = P.ghost_time(t, ratio, valid, rel, excluded=(t >= 2.5) & (t < 3.0))
    assert g.time_s == pytest.approx(1.0, abs=0.11)
    # held to the end: censored, the whole remaining time
    g = P.ghost_time(t, np.zeros(len(t)), valid, rel)
    assert g.censored and g.time_s == pytest.approx(8.0 - 0.1, abs=0.11)
    # a person coming back ends the ghost's share of the hold
    g = P.ghost_time(t, np.zeros(len(t)), valid, rel | ((t > 4.0) & (t < 5.0)))
    assert g.holds[0] == pytest.approx(2.0, abs=0.11)
    # at ≥ 80 % right away: no ghost; a stopped reference (invalid) is no recovery
    assert P.ghost_time(t, np.full(len(t), 0.85), valid, rel).time_s == 0.0
    assert P.ghost_time(t, np.ones(len(t)), np.zeros(len(t), bool), rel).censored
    assert P.ghost_time(t, ratio, valid, np.zeros(len(t), bool)).holds == []


def test_relevant_people_are_near_and_not_behind():
    robot = np.zeros((3, 2))
    yaw = np.zeros(3)
    centres = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 2.0]])
    gaps = [np.array([0.5, 0.5, 2.0])]
    assert P.relevant(robot, yaw, [centres], gaps).tolist() == [True, False, False]


def test_command_ratio_takes_the_latest_commands():
    ratio, valid = P.command_ratio(np.array([0.0, 1.0, 2.0, 3.0]), np.array([0.5, 1.5]), np.array([0.5, 0.0]),
                                   np.array([0.9, 2.5]), np.array([0.25, 0.1]))
    assert not valid[0] and valid[1] and not valid[2] and not valid[3]  # before any; a zero reference
    assert ratio[1] == pytest.approx(0.5)


def test_map_lag_finds_the_shift_of_a_walkers_track():
    track = P.Track(np.arange(0, 5, 0.1), np.column_stack([np.arange(0, 5, 0.1) * 1.2, np.zeros(50)]),
                    np.tile([1.2, 0.0], (50, 1)))
    tau, resid = P.best_shift(track, 3.0, track.at(3.0 - 0.4)[0])
    assert tau == pytest.approx(0.4, abs=0.011) and resid < 0.02
    assert P.map_centroid(np.array([[0.0, 0.0], [0.2, 0.0], [5.0, 5.0]]), np.array([0.1, 0.0])) == \
        pytest.approx([0.1, 0.0])
    assert P.map_centroid(np.zeros((0, 2)), np.zeros(2)) is None


@settings(max_examples=40, deadline=None)
@given(st.floats(0.02, 0.4), st.integers(0, 2**31 - 1))
def test_tracker_errors_recover_the_velocity_noise_and_count_false_tracks(sigma, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 10.0, 0.1)
    walker = P.Track(t, np.column_stack([-3.0 + 1.2 * t, np.ones_like(t)]), np.tile([1.2, 0.0], (len(t), 1)))
    stander = P.Track(t, np.tile([2.0, -1.0], (len(t), 1)))
    obs = []
    for k, tk in enumerate(t[:-1]):
        for tr in (walker, stander):
            noise = rng.normal(0.0, sigma, 2)
            obs.append((tk, 100.0 * k, tr.at(tk)[0] + [0.05, 0.0], tr.velocity_at(tk)[0] + noise))
    obs.append((5.0, 1000.0, np.array([9.0, 9.0]), np.zeros(2)))  # nobody there
    errors = P.tracker_errors(obs, [walker, stander], settled_ms=300.0)
    half = P.tracker_errors(obs[: len(obs) // 2], [walker, stander], 300.0)
    pooled = (half + P.tracker_errors(obs[len(obs) // 2:], [walker, stander], 300.0)).summary()
    out = errors.summary()
    assert out["false_tracks"] == 1 and out["matched"] == 2 * (len(t) - 1)
    assert out["settled"] == 2 * (len(t) - 4)  # tracked 0, 100 and 200 ms are young
    # 196 pairs: the RMS of 392 N(0, σ) draws is σ within ~4 standard errors
    assert out["velocity_sigma_settled_m_s"] == pytest.approx(sigma, rel=0.2)
    assert out["position_error_p50_m"] == pytest.approx(0.05, abs=1e-3)
    assert pooled == out


@pytest.mark.parametrize("case", crowd_cases(), ids=lambda c: c["name"])
def test_every_default_case_is_a_fair_conflict(case):
    """Had the robot kept its reference, it would have touched the person; and the person was in the
    camera's view for at least 1 s of the 3 s before."""
    nominal = crowd_nominal(case)
    walker = nominal["walker"]
    assert walker["contact_s"] is not None and walker["min_gap_m"] < -0.1
    assert walker["in_view_before_s"] >= 1.0
    assert walker["contact_s"] < case["drive_s"] - 2.0  # time left to see the robot go on afterwards
    for spec in case["walkers"]:
        assert spec["speed"] <= 1.5
        assert all(abs(x) <= 6.0 - 0.3 and abs(y) <= 3.0 - 0.3 for x, y in spec["waypoints"])
    if case["seed"] >= 1:
        assert nominal["passer"]["contact_s"] is None  # the second person passes beside the lane


def test_default_set_is_four_kinds_by_two_speeds_by_three_seeds():
    cases = crowd_cases()
    assert len(cases) == 24 == len({c["name"] for c in cases})
    assert {c["kind"] for c in cases} == set(CROWD_KINDS) and {c["speed"] for c in cases} == set(CROWD_SPEEDS)
    assert max(c["speed"] for c in cases) == 1.5
    assert crowd_case("head_on", 1.5, 2) == crowd_case("head_on", 1.5, 2)  # seeded
    with pytest.raises(ValueError):
        crowd_case("dancing", 1.0, 0)
    with pytest.raises(ValueError):
        crowd_case("crossing", 2.0, 0)


def test_variants_are_real_or_the_static_barrier_alone():
    assert list(bench.variant_args(False)) == ["static"]
    real = bench.variant_args(True)
    assert "object_motion=false" in real["static"] and "object_motion=true" in real["motion"]
    assert "evade=true" in real["evade"] and "evade=true" not in real["motion"]
    # This tree's filter has the setting: the bench must find it, or it would run the baseline alone.
    assert bench.object_motion_available()


def _state(t: float, x: float, v: float) -> RobotState:
    return RobotState(header=Header(stamp_ns=int(t * 1e9)), position=(x, 0.0, 0.0), orientation=(0, 0, 0, 1),
                      linear_velocity=(v, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0))


def test_case_metrics_from_recorded_messages():
    """A robot that drives into a person standing in its lane, then stops: an at-fault contact; it is
    held 1 s after the person steps away; a second person crossing farther ahead is shown by the map
    0.4 s late (frames of 0.3 s old positions, received 0.1 s after their stamp)."""
    case = {"name": "t", "kind": "head_on", "speed": 1.0, "seed": 0, "v_ref": 0.5}
    t = np.arange(100.0, 106.0, 0.02)
    x = np.where(t < 102.0, -2.0 + 0.5 * (t - 100.0), -1.0)
    v = np.where(t < 102.0, 0.5, 0.0)
    states = [_state(a, b, c) for a, b, c in zip(t, x, v, strict=True)]
    person = ade20k.index("person")

    def near(tt: float) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        if tt < 103.0:
            return (-0.65, 0.0, 0.0), (0.0, 0.0, 0.0)  # overlapping the stopped robot's nose
        y = min(1.5 * (tt - 103.0), 1.5)
        return (-0.65, y, 0.0), (0.0, 1.5 if y < 1.5 else 0.0, 0.0)

    def far(tt: float) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        return (1.5, -1.0 + 1.2 * (tt - 100.0), 0.0), (0.0, 1.2, 0.0)

    actors = [SimActors(header=Header(stamp_ns=int(a * 1e9)), actors=[
        SimActor(name=n, label=person, position=f(a)[0], velocity=f(a)[1], radius=0.22, height=1.7)
        for n, f in (("walker", near), ("passer", far))]) for a in np.arange(100.0, 106.0, 0.1)]
    refs = [VelocityCommand(header=Header(stamp_ns=int(a * 1e9)), linear=(0.5, 0, 0), angular=(0, 0, 0), source="t")
            for a in np.arange(100.0, 106.0, 0.05)]
    safes = [VelocityCommand(header=Header(stamp_ns=int(a * 1e9)), angular=(0, 0, 0), source="f",
                             linear=(0.5 if (a < 101.9 or a >= 105.0) else 0.0, 0, 0))
             for a in np.arange(100.0, 106.0, 0.02)]
    esdfs = []
    for s in np.arange(101.0, 102.2, 0.1):
        dist = np.full((100, 60, 1), 1.0, np.float32)
        groups = np.zeros((100, 60, 1), np.uint8)
        px, py = far(s - 0.3)[0][:2]
        i, j = round((px + 3.0) / 0.05), round((py + 1.5) / 0.05)
        dist[i - 2:i + 3, j - 2:j + 3] = -0.1
        groups[i - 2:i + 3, j - 2:j + 3] = 1
        esdfs.append((s + 0.1, EsdfGrid(header=Header(stamp_ns=int(s * 1e9)), origin=(-3.0, -1.5, 0.0),
                                        voxel_size=0.05, distance=dist, risk_group=groups,
                                        groups=["high", "mid", "low"], max_distance=2.0,
                                        unknown_is_occupied=False)))
    status = [SafetyStatus(header=Header(stamp_ns=int(a * 1e9)), h=1.0, risk_group=0, intervening=False,
                           fallback=None, solve_us=10.0, esdf_age_ms=100.0) for a in np.arange(100.0, 106.0, 0.02)]
    row = bench.case_metrics(case, states, refs, safes, actors, esdfs, 100.0, status)
    assert row["at_fault_contacts"] > 0 and row["max_at_fault_speed"] == pytest.approx(0.5)
    assert row["people"]["walker"]["at_fault_samples"] > 0 and row["people"]["passer"]["at_fault_samples"] == 0
    assert row["min_clearance_m"] < 0 and row["walkers"] == 2
    # the walker stops being relevant once 1.1 m from the stopped body (its nose's corner at x = -0.839)
    left = 103.0 + (0.11 + math.sqrt((1.1 + 0.22) ** 2 - 0.189 ** 2)) / 1.5
    assert row["ghost_time_s"] == pytest.approx(105.0 - left, abs=0.05) and not row["ghost_censored"]
    assert row["map_lag_median_s"] == pytest.approx(0.4, abs=0.05) and row["maps_with_person_in_view"] >= 10
    assert row["progress"] == pytest.approx(1.0 / 6.0 / 0.5, abs=0.01)
    # the robot braked by the fail-safe all along: no ghost is the map's
    braking = [st.model_copy(update={"fallback": "stale_map"}) for st in status]
    assert bench.case_metrics(case, states, refs, safes, actors, esdfs, 100.0, braking)["ghost_time_s"] == 0.0


@pytest.mark.slow
def test_two_crowd_cases_through_the_full_stack(tmp_path):
    """`riskfield bench crowd` end to end on two cases (one with two people): the people's ground
    truth reached the metrics, the map was compared with it, the outputs are written."""
    from typer.testing import CliRunner

    out = tmp_path / "crowd"
    result = CliRunner().invoke(bench.app, ["--perception", "gt", "--kinds", "head_on,crossing", "--speeds", "1.5",
                                            "--seeds", "1", "--out", str(out)])
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    # Both variants ran: the filter's motion barrier beside the static baseline (not the baseline alone).
    assert summary["variants"] == ["motion", "static"] and not summary["baseline_is_static_only"]
    for variant in summary["variants"]:
        rows = summary["cases"][variant]
        assert [r["name"] for r in rows] == ["head_on_1.5_s1", "crossing_1.5_s1"]
        for r in rows:
            assert r["walkers"] == 2 and set(r["people"]) == {"walker", "passer"}
            assert r["maps_with_person_in_view"] > 0 and len(r["path"]) > 100
            assert r["case_wall_s"] < 90
        assert summary["totals"][variant]["cases"] == 2
        assert (out / f"crowd_{variant}.png").stat().st_size > 0
    assert "| Variant |" in (out / "tables.md").read_text()


def test_demo_summary_reports_the_walkers_clearance_contacts_and_ghost_time():
    from riskfield.experiments.demo.report import Streams, people_summary

    st = Streams()
    person = ade20k.index("person")
    for k in range(300):  # 6 s at 50 Hz: the robot drives along y = -1.7, stops at 1 s for 2.5 s
        t = k * 0.02
        x = 0.6 + 0.4 * min(t, 1.0) + 0.4 * max(0.0, t - 3.5)
        moving = t < 1.0 or t >= 3.5
        st.state_t.append(t)
        st.xy.append((x, -1.7))
        st.yaw.append(0.0)
        st.velocity.append((0.4 if moving else 0.0, 0.0))
        st.omega.append(0.0)
        st.ref_t.append(t)
        st.ref.append(VelocityCommand(linear=(0.4, 0, 0), angular=(0, 0, 0), source="nav"))
        st.safe_t.append(t)
        st.safe.append(VelocityCommand(linear=(0.4 if moving else 0.0, 0, 0), angular=(0, 0, 0), source="f"))
    for k in range(60):  # the crosser walks south across the leg 0.9 m ahead of the stopped robot
        t = k * 0.1
        y = max(-0.75 - 1.2 * max(0.0, t - 0.5), -3.2)
        st.actors_t.append(t)
        st.actors.append(SimActors(actors=[SimActor(name="crosser", label=person, position=(1.9, y, 0.0),
                                                    velocity=(0.0, -1.2 if -3.2 < y < -0.75 else 0.0, 0.0),
                                                    radius=0.22, height=1.7)]))
    out = people_summary(st, (0.0, 6.0))
    assert out["walkers"] == ["crosser"]
    assert out["min_clearance_m"] == pytest.approx(1.9 - 1.0 - 0.161 - 0.22, abs=0.01)
    assert out["at_fault_contacts"] == 0 and out["person_contacts"] == 0
    # relevant while within 1.1 m of the stopped body (|dy| ≤ 0.11 + √(1.32² − 0.739²) off its axis), then
    # held by the filter until the robot drives on at 3.5 s: that hold is the ghost
    left = 0.5 + (1.7 + 0.11 + math.sqrt(1.32 ** 2 - 0.739 ** 2) - 0.75) / 1.2
    assert out["ghost_time_s"] == pytest.approx(3.5 - left, abs=0.03) and not out["ghost_censored"]
    json.dumps(out)  # the demo writes it with the standard library: Python types only


def test_the_demos_walker_crosses_the_first_leg_ahead_of_the_robot_in_view():
    """Spawned as the robot starts the loop's first leg: on the nominal drive (the navigator's 0.4 m/s
    along the leg from the spawn, no reaction) the walker crosses the leg ahead of the robot, in the
    camera's view for a second before, and never touches it."""
    from riskfield.experiments.scenarios import CROSSER, LOOP, placed_object

    walker = placed_object(CROSSER)
    t = np.arange(0.0, 8.0, 0.02)
    robot = np.column_stack([np.minimum(LOOP[0][0] + 0.4 * t, LOOP[1][0]), np.full(len(t), LOOP[0][1])])
    yaw = np.zeros(len(t))
    centres = np.array([walker.state_at(float(a))[0][:2, 3] for a in t])
    gap, _ = P.rectangle_gap(robot, yaw, centres, walker.footprint_radius)
    crossing = float(t[np.argmin(np.abs(centres[:, 1] - LOOP[0][1]))])
    assert walker.state_at(crossing)[1][1] == pytest.approx(-1.2)  # at 1.2 m/s, southwards
    assert robot[np.searchsorted(t, crossing), 0] < CROSSER["position"][0] - 0.5  # ahead of the robot
    assert gap.min() > 0.3
    view = P.in_view(robot, yaw, centres, walker.footprint_radius)
    assert P.seen_before(t, view, crossing) >= 1.0
