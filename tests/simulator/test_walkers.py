"""Walkers: waits along a path (start late, stop, stop and turn), their velocities, walkers in
procedural rooms, and the world's ground truth of moving objects (``World.actors``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import ade20k
from riskfield.services.simulator import procedural
from riskfield.services.simulator.scenario import ObjectSpec, load_scenario
from riskfield.services.simulator.scene import Motion
from riskfield.services.simulator.world import World

coord = st.integers(-40, 40).map(lambda i: i / 10)  # legs are 0 or ≥ 0.1 m: no sub-millimetre corners
point = st.tuples(coord, coord)


def test_waits_start_late_stop_and_turn_back():
    m = Motion(np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 0.0]]), speed=1.0, mode="once",
               waits=np.array([1.0, 3.0, 0.0]))
    p, yaw, v = m.state(np.zeros(2), 0.5, 0.5)  # still waiting at the start, facing the first leg
    np.testing.assert_allclose(p, [0, 0])
    np.testing.assert_allclose(v, [0, 0])
    assert yaw == pytest.approx(0.0)
    p, _, v = m.state(np.zeros(2), 0.0, 2.0)  # walking out
    np.testing.assert_allclose(p, [1, 0])
    np.testing.assert_allclose(v, [1, 0])
    p, yaw, v = m.state(np.zeros(2), 0.0, 4.5)  # standing at the far end, as it came
    np.testing.assert_allclose(p, [2, 0])
    np.testing.assert_allclose(v, [0, 0])
    assert yaw == pytest.approx(0.0)
    p, yaw, v = m.state(np.zeros(2), 0.0, 6.5)  # turned, walking back
    np.testing.assert_allclose(p, [1.5, 0])
    np.testing.assert_allclose(v, [-1, 0])
    assert abs(abs(yaw) - math.pi) < 1e-9
    p, _, v = m.state(np.zeros(2), 0.0, 100.0)  # once: back at the start and still
    np.testing.assert_allclose(p, [0, 0], atol=1e-12)
    np.testing.assert_allclose(v, [0, 0])


def test_pingpong_with_waits_repeats_and_bad_waits_are_refused():
    m = Motion(np.array([[0.0, 0.0], [1.0, 0.0]]), speed=1.0, mode="pingpong", waits=np.array([0.5, 0.5]))
    period = 3.0  # wait, walk, wait, walk back
    for t in (0.2, 1.0, 1.7, 2.4):
        np.testing.assert_allclose(m.place(np.zeros(2), 0, t)[0], m.place(np.zeros(2), 0, t + 2 * period)[0])
    for bad in ([1.0], [-1.0, 0.0], [math.nan, 0.0]):
        with pytest.raises(ValueError):
            Motion(np.array([[0.0, 0.0], [1.0, 0.0]]), waits=np.array(bad))
    with pytest.raises(ValueError):
        ObjectSpec.model_validate({"class": "person", "waypoints": [[0, 0], [1, 0]], "waits": [1.0]})
    with pytest.raises(ValueError):
        ObjectSpec.model_validate({"class": "person", "waits": [1.0]})


@settings(max_examples=60, deadline=None)
@given(path=st.lists(point, min_size=2, max_size=5), speed=st.floats(0.1, 1.5),
       waits=st.lists(st.floats(0.0, 2.0), min_size=5, max_size=5), mode=st.sampled_from(["once", "pingpong", "loop"]),
       t=st.floats(0.0, 30.0))
def test_a_walker_moves_continuously_at_its_speed_and_reports_that_velocity(path, speed, waits, mode, t):
    m = Motion(np.array(path), speed, mode, waits=np.array(waits[:len(path)]))
    dt = 1e-3
    p0, _, v0 = m.state(np.zeros(2), 0.0, t)
    p1, _, _ = m.state(np.zeros(2), 0.0, t + dt)
    step = float(np.hypot(*(p1 - p0)))
    assert step <= speed * dt * (1 + 1e-6) + 1e-9  # never faster than its speed, never a jump
    assert float(np.hypot(*v0)) in (pytest.approx(0.0), pytest.approx(speed))
    if step == pytest.approx(speed * dt, rel=1e-6) and np.any(v0):  # within one leg: the velocity is the motion's
        np.testing.assert_allclose((p1 - p0) / dt, v0, atol=1e-3 * speed + 1e-6)


def test_walkers_in_a_random_room_leave_the_other_objects_as_they_were():
    base = procedural.random_placements(5, 7.0, 6.0, keep_clear=(-2.0, 0.0, 0.8))
    walking = procedural.Furnishing(walkers=3, walker_speed=(1.0, 1.5))
    more = procedural.random_placements(5, 7.0, 6.0, walking, keep_clear=(-2.0, 0.0, 0.8))
    assert more[:len(base)] == base
    walkers = more[len(base):]
    assert len(walkers) == 3 and all(w.class_name == "person" and w.waypoints for w in walkers)
    assert all(1.0 <= w.speed <= 1.5 for w in walkers)
    assert more == procedural.random_placements(5, 7.0, 6.0, walking, keep_clear=(-2.0, 0.0, 0.8))
    fixed = [(p.x, p.y, 0.5 * math.hypot(p.size[0], p.size[1])) for p in base] + [(-2.0, 0.0, 0.8)]
    for w in walkers:
        (ax, ay), (bx, by) = w.waypoints
        assert math.hypot(bx - ax, by - ay) >= 1.5
        r = w.size[0] / 2
        for s in np.linspace(0, 1, 50):  # the whole path keeps clear of every fixed object
            x, y = ax + s * (bx - ax), ay + s * (by - ay)
            assert abs(x) <= 3.5 - r and abs(y) <= 3.0 - r
            assert all(math.hypot(x - fx, y - fy) >= r + fr for fx, fy, fr in fixed)


def test_world_reports_its_moving_objects_with_velocities():
    world = World(load_scenario({
        "name": "walkers", "room": {"size": [8.0, 6.0]}, "procedural": {"seed": 2, "furniture": 1, "boxes": 0,
                                                                       "balls": 0, "people": 1, "animals": 0,
                                                                       "walkers": 2},
        "objects": [{"class": "person", "name": "crosser", "position": [1.0, -2.0],
                     "waypoints": [[1.0, -2.0], [1.0, 2.0]], "speed": 1.2, "motion": "once"},
                    {"class": "chair", "position": [-2.0, 2.0]}]}))
    assert [a.name for a in world.actors()] == ["proc_person_2", "proc_person_3", "crosser"]
    world.advance(1.0)
    crosser = world.actors()[-1]
    assert crosser.label == ade20k.index("person")
    np.testing.assert_allclose(crosser.position, [1.0, -0.8, 0.0], atol=1e-6)
    np.testing.assert_allclose(crosser.velocity, [0.0, 1.2, 0.0], atol=1e-9)
    assert crosser.radius == pytest.approx(0.22, abs=1e-3) and crosser.height == pytest.approx(1.7, abs=1e-3)
    for a in world.actors()[:2]:
        assert math.hypot(*a.velocity[:2]) == pytest.approx(math.hypot(*a.velocity[:2]))
        assert 0.5 <= math.hypot(*a.velocity[:2]) <= 1.5
    world.advance(5.0)  # "once": arrived and still
    np.testing.assert_allclose(world.actors()[-1].velocity, [0, 0, 0])
    late = world.add_object({"class": "person", "name": "late", "position": [0, 0], "velocity": [0.5, 0.0],
                             "appear_at_s": 100.0})
    assert late not in [a.name for a in world.actors()]  # not present yet


def test_random_rooms_have_walkers_and_keep_their_fixed_objects():
    from riskfield.services.simulator.scenario import RANDOM_WALKERS, build_scene

    world = World("random:3")
    walkers = world.actors()
    # a walker that finds no clear path of 1.5 m in a crowded room is left out, like any object
    assert 1 <= len(walkers) <= RANDOM_WALKERS and all(a.label == ade20k.index("person") for a in walkers)
    world.advance(1.0)
    assert all(0.5 <= math.hypot(*a.velocity[:2]) <= 1.5 for a in world.actors())
    still = build_scene(load_scenario({"name": "r", "room": None, "procedural": {"seed": 3}}))
    assert [o.name for o in still.objects] == [o.name for o in world.scene.objects][:len(still.objects)]
