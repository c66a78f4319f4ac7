"""Evasion on request (``evade``): a retreat from someone who keeps coming at the stopped robot,
at ``evade_speed`` and within ``evade_distance``, only into floor the map observed free, never for
someone who is not on a collision course, and off by default."""

from __future__ import annotations

import numpy as np
import pytest

from riskfield.protocol import EsdfGrid, Header, TrackedObject, TrackedObjects, VelocityCommand
from riskfield.services.fields import AnalyticField, EsdfField, to_esdf
from riskfield.services.geometry.shapes import Plane, Sphere
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.evade import Evader, FreeFloor
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.motion import object_table
from riskfield.services.safety_filter.state import FilterState
from riskfield.services.safety_filter.supervisor import FilterSupervisor

GROUPS = ["high", "mid", "low"]
PERSON, MARGIN = 0.22, 0.15
ON = FilterConfig(evade=True)


def person(x: float, y: float = 0.0, vx: float = 0.0, vy: float = 0.0) -> TrackedObject:
    return TrackedObject(id=1, label=12, risk_group=1, position=(x, y, 0.0), velocity=(vx, vy, 0.0),
                         radius=PERSON, age_ms=0.0, tracked_ms=2000.0)


def field(*people: tuple[float, float], walls: tuple = ()) -> EsdfField:
    shapes = [Sphere((x, y, 0.0), PERSON + MARGIN, label=1, planar=True) for x, y in people]
    shapes += [Plane.through(p, n, label=3) for p, n in walls]
    shapes = shapes or [Plane.through((0.0, -2.9, 0.0), (0.0, 1.0, 0.0), label=3)]
    return to_esdf(AnalyticField(shapes, groups=GROUPS), [-3.0, -3.0, 0.0], [3.0, 3.0, 0.0], 0.05, planar=True)


def floor(f: EsdfField, x_min: float = -np.inf, x_max: float = np.inf) -> FreeFloor:
    """Observed free: the field's free cells with x in [x_min, x_max] (the rest unknown)."""
    nx = f.distance.shape[0]
    x = f.origin[0] + f.voxel_size * np.arange(nx)
    free = (f.distance[..., 0] > 0) & ((x >= x_min) & (x <= x_max))[:, None]
    return FreeFloor(np.asarray(f.origin[:2], float), f.voxel_size, free)


def table(*objs: TrackedObject) -> np.ndarray:
    return object_table(list(objs), ON.model_copy(update={"command_delay_s": 0.0}), 0, 0)


def evader(cfg: FilterConfig = ON) -> tuple[Evader, SafetyFilter]:
    filt = SafetyFilter(cfg)
    return Evader(filt.model, cfg, filt.delta), filt


HERE = FilterState.planar(0.0, 0.0, 0.0)


def test_someone_coming_at_the_stopped_robot_is_retreated_from_into_free_floor():
    ev, filt = evader()
    f = field((0.8, 0.0))
    u = ev.command(HERE, table(person(0.8, vx=-1.0)), filt.gains.for_groups(GROUPS), f, floor(f))
    assert u is not None and u[0] == pytest.approx(-ON.evade_speed) and u[1] == 0.0
    # From behind: forwards, where the floor was seen.
    f = field((-0.8, 0.0))
    u = ev.command(HERE, table(person(-0.8, vx=1.0)), filt.gains.for_groups(GROUPS), f, floor(f))
    assert u is not None and u[0] == pytest.approx(ON.evade_speed)


def test_evasion_is_off_by_default():
    ev, filt = evader(FilterConfig())
    f = field((0.8, 0.0))
    assert ev.command(HERE, table(person(0.8, vx=-1.0)), filt.gains.for_groups(GROUPS), f, floor(f)) is None


def test_unknown_floor_is_not_free_and_a_wall_behind_stops_the_retreat():
    ev, filt = evader()
    f = field((0.8, 0.0))
    gains = filt.gains.for_groups(GROUPS)
    obj = table(person(0.8, vx=-1.0))
    assert ev.command(HERE, obj, gains, f, floor(f, x_min=-0.1)) is None  # nothing seen behind the body
    assert ev.command(HERE, obj, gains, f, None) is None  # a map without the layer: no retreat
    # Seen free up to a wall 0.35 m behind the rear bumper: the swept footprint would reach it.
    walled = field((0.8, 0.0), walls=(((-0.5, 0.0, 0.0), (1.0, 0.0, 0.0)),))
    assert ev.command(HERE, obj, gains, walled, floor(f)) is None


def test_someone_walking_past_starts_no_retreat():
    ev, filt = evader()
    f = field((1.0, 0.75))
    assert ev.command(HERE, table(person(1.0, 0.75, vx=-1.0)), filt.gains.for_groups(GROUPS), f, floor(f)) is None
    assert ev.command(HERE, None, filt.gains.for_groups(GROUPS), f, floor(f)) is None


def test_a_retreat_ends_after_evade_distance():
    ev, filt = evader(FilterConfig(evade=True, evade_distance=0.2))
    f = field((0.8, 0.0))
    gains, moved = filt.gains.for_groups(GROUPS), []
    for k in range(12):  # the person keeps coming as the robot backs away by 0.03 m a step
        s = FilterState.planar(-0.03 * k, 0.0, 0.0)
        xp = 0.8 - 0.03 * k
        moved.append(ev.command(s, table(person(xp, vx=-0.5)), gains, field((xp, 0.0)), floor(f)) is not None)
    assert moved[:6] == [True] * 6 and not any(moved[8:])  # 0.2 m: the 7th step's 0.21 m ends it


def grid_message(f: EsdfField, free: FreeFloor | None) -> EsdfGrid:
    return EsdfGrid(header=Header(stamp_ns=1), origin=tuple(f.origin.tolist()), voxel_size=f.voxel_size,
                    distance=f.distance.astype(np.float32), risk_group=f.risk_groups.astype(np.uint8),
                    groups=GROUPS, max_distance=2.0, unknown_is_occupied=False,
                    observed_free=None if free is None else free.free[..., None].astype(np.uint8))


@pytest.mark.parametrize("ref", [0.0, 0.3])
def test_the_supervisor_retreats_only_with_evade_on_and_says_so(ref):
    f = field((0.8, 0.0))
    for cfg, layer, expect in ((ON, True, -ON.evade_speed), (FilterConfig(), True, 0.0), (ON, False, 0.0)):
        sup = FilterSupervisor(SafetyFilter(cfg), 0.3, 10.0, 10.0)
        sup.on_map(grid_message(f, floor(f) if layer else None), 0.0)
        sup.on_state(FilterState.planar(0.0, 0.0, 0.0), 0.0)
        sup.on_objects(TrackedObjects(header=Header(stamp_ns=0), objects=[person(0.8, vx=-1.0)]), 0.0)
        sup.on_ref(VelocityCommand(linear=(ref, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="joy"), 0.0)
        cmd, status = sup.tick(0.05)
        assert cmd.linear[0] == pytest.approx(expect, abs=1e-6) and cmd.angular == (0.0, 0.0, 0.0)
        assert status.evading == (expect != 0.0) and status.fallback is None


def test_a_released_dead_man_never_retreats():
    f = field((0.8, 0.0))
    sup = FilterSupervisor(SafetyFilter(ON), 0.3, 10.0, 10.0)
    sup.on_map(grid_message(f, floor(f)), 0.0)
    sup.on_state(FilterState.planar(0.0, 0.0, 0.0), 0.0)
    sup.on_objects(TrackedObjects(header=Header(stamp_ns=0), objects=[person(0.8, vx=-1.0)]), 0.0)
    sup.on_ref(VelocityCommand(linear=(0.0, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="joy", engaged=False), 0.0)
    cmd, status = sup.tick(0.05)
    assert cmd.linear == (0.0, 0.0, 0.0) and not status.evading
