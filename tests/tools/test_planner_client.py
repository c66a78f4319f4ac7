"""The planner client (riskfield.client): the filter's answers on a grid, segment checks, the live key,
and the planner example against a live mapping node over a real router."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from pathlib import Path

import msgpack
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from riskfield.client import FILTER_INTERPOLATION, EsdfClient, EsdfMap
from riskfield.protocol import (
    DistanceQuery,
    EsdfGrid,
    Header,
    Keys,
    NavGoal,
    PerceptionFrame,
    RobotState,
    ade20k,
    encode,
)
from riskfield.services.fields import EsdfField, answer_query
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Plane, render
from riskfield.services.geometry.transforms import orbit
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_matched, wait_until

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "esdf_planner.py"


def wall_grid(stamp_ns: int = 1) -> EsdfGrid:
    """4 m × 2 m at 5 cm: a wall along x = 2 m for y < 1.4 m (signed distance, 5 cm thick)."""
    vs = 0.05
    X, Y = np.meshgrid(np.arange(81) * vs, np.arange(41) * vs, indexing="ij")
    d = np.hypot(X - 2.0, np.maximum(Y - 1.4, 0.0)) - 0.05
    rg = np.where(d < 1.0, 2, 0).astype(np.uint8)
    return EsdfGrid(header=Header(stamp_ns=stamp_ns), origin=(0, 0, 0), voxel_size=vs,
                    distance=d[:, :, None].astype(np.float32), risk_group=rg[:, :, None],
                    groups=["high", "mid", "low"], max_distance=2.0, unknown_is_occupied=False)


def test_the_default_interpolation_is_the_filters():
    assert FilterConfig().interpolation == FILTER_INTERPOLATION


@given(st.lists(st.tuples(st.floats(-0.5, 4.5), st.floats(-0.5, 2.5), st.floats(-1, 1)), min_size=1, max_size=20),
       st.sampled_from(["trilinear", "catmull_rom", "bspline_smooth"]))
def test_answers_are_the_filters_and_the_query_services(pts, interpolation):
    """Distance, gradient, risk group and the in-map flag equal the services' field on the same grid
    (what the filter reads and ``map/esdf/query`` answers), inside the map and out of it."""
    grid = wall_grid()
    m = EsdfMap(grid, interpolation)
    p = np.array(pts)
    want = answer_query(EsdfField.from_grid(grid, interpolation), p)
    got = m.query(p)
    np.testing.assert_array_equal(got.inside, want.inside)
    np.testing.assert_allclose(got.distance, want.distance, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.gradient, want.gradient, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got.risk_group, want.risk_group)
    np.testing.assert_array_equal(m.inside(p), EsdfField.from_grid(grid).inside(p))
    outside = ~want.inside
    assert np.all(got.distance[outside] == 2.0) and np.all(got.gradient[outside] == 0)


def test_queries_in_the_plane_and_by_name():
    m = EsdfMap(wall_grid())
    d = m.distance([[1.0, 0.5], [2.0, 0.5]])  # (N, 2): z = 0, ignored by a slice anyway
    assert 0.9 < d[0] < 0.96 and d[1] < 0.0
    g = m.gradient([[1.0, 0.5, 0.3]])[0]
    np.testing.assert_allclose(g, [-1.0, 0.0, 0.0], atol=0.02)
    assert m.risk_group([[1.5, 0.5], [0.0, 0.5], [9.0, 9.0]]) == ["mid", None, None]
    lo, hi = m.bounds()
    np.testing.assert_allclose(lo, [0, 0, 0]) and np.testing.assert_allclose(hi, [4.0, 2.0, 0.0])


def test_segment_clear_with_margin():
    m = EsdfMap(wall_grid())
    across = m.segment_clear((0.5, 0.5, 0), (3.5, 0.5, 0), margin=0.2)
    assert not across.clear and across.min_distance < 0 and abs(across.at - 0.5) < 0.02
    assert "from an obstacle at 0.50 of its length" in across.reason
    over = m.segment_clear((0.5, 1.8, 0), (3.5, 1.8, 0), margin=0.2)  # beyond the wall's end at y = 1.4
    assert over.clear and over.reason is None and 0.3 < over.min_distance < 0.4
    assert not m.segment_clear((0.5, 1.8, 0), (3.5, 1.8, 0), margin=0.4).clear  # the margin decides
    out = m.segment_clear((0.5, 1.8, 0), (0.5, 2.2, 0), margin=0.0)  # leaves the map at y = 2.0
    assert not out.clear and "leaves the map" in out.reason and abs(out.at - 0.5) < 0.05
    short = m.segment_clear((1.0, 0.5), (1.0, 0.5), margin=0.5)  # a point: both ends are the one sample
    assert short.clear and abs(short.min_distance - m.distance([[1.0, 0.5]])[0]) < 1e-12


def test_bad_arguments_are_refused():
    m = EsdfMap(wall_grid())
    for bad in ([[np.nan, 0, 0]], [[1, 2, 3, 4]], np.zeros((2, 2, 3))):
        try:
            m.query(bad)
        except ValueError:
            continue
        raise AssertionError(f"accepted {bad!r}")
    for kwargs in ({"margin": np.inf}, {"step": 0.0}, {"step": -1.0}):
        try:
            m.segment_clear((0, 0), (1, 1), **kwargs)
        except ValueError:
            continue
        raise AssertionError(f"accepted {kwargs}")


def test_client_keeps_the_newest_map_and_counts_bad_ones(router_endpoint: str):
    keys = Keys("t_client")
    with client_session(router_endpoint) as s, EsdfClient(router_endpoint, robot=keys.robot) as esdf:
        assert esdf.latest is None and esdf.wait(0.0) is None
        assert wait_matched(s, keys.esdf)
        put(s, keys.esdf, wall_grid(stamp_ns=100))
        m = esdf.wait(10.0)
        assert m is not None and m.stamp_ns == 100
        s.put(keys.esdf, msgpack.packb({"schema": "EsdfGrid/1", "origin": "x"}))
        put(s, keys.esdf, wall_grid(stamp_ns=50))  # older than the one held: ignored
        put(s, keys.esdf, wall_grid(stamp_ns=200))
        assert esdf.wait(10.0, newer_than_ns=100).stamp_ns == 200
        assert wait_until(lambda: esdf.rejected == 1, 5)
        assert esdf.latest.stamp_ns == 200


CAM = PinholeCamera.centred(160, 120, 125.0)


def room_frames(n: int = 4) -> list[PerceptionFrame]:
    """A wall at x = 1.5 m, the floor and a person-sized box at x 0.8..1.0, y -0.7..-0.4, seen from
    an orbit about (1.2, 0, 0.3)."""
    scene = [Plane((1, 0, 0), 1.5, ade20k.index("wall")), Plane((0, 0, 1), 0.0, ade20k.index("floor")),
             Box((0.8, -0.7, 0.0), (1.0, -0.4, 1.2), ade20k.index("person"))]
    out = []
    for i, T in enumerate(orbit([1.2, 0.0, 0.3], n=n, radius=0.2, height=0.3)):
        pts, conf, lab = render(scene, T, CAM)
        out.append(PerceptionFrame(T_WC=T, points=pts, confidence=conf, labels=lab, keyframe_id=i))
    return out


def test_example_plans_on_a_live_mapping_node(router_endpoint: str):
    """The example, in its own process, against the mapping node's published ESDF: it plans around
    the person, every waypoint segment is clear by the filter's own field, and the goal reaches the
    navigator's key."""
    keys = Keys("t_client_live")
    args = ["--robot", keys.robot, "--set", "esdf_rate_hz=20"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")), proc.output
        # liveliness comes before the node has loaded its kernels: its query service answers once it has
        probe = encode(DistanceQuery(points=np.zeros((1, 3))))
        assert wait_until(lambda: any(r.ok is not None for r in s.get(keys.esdf_query, payload=probe, timeout=0.5)),
                          60, 0.1), proc.output
        goals = Collector(s, keys.nav_goal, NavGoal)
        example = subprocess.Popen([sys.executable, str(EXAMPLE), "--connect", router_endpoint, "--robot", keys.robot,
                                    "--start", "0.3", "-0.2", "--goal", "0.9", "-1.2", "--z", "0.1",
                                    "--clearance", "0.1", "--timeout", "60", "--send-goal"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            # the example's subscriber is known before the first map is made (a map is published on new data)
            assert wait_matched(s, keys.esdf, 30), example.stderr.read() if example.poll() is not None else ""
            grids = Collector(s, keys.esdf, EsdfGrid)
            put(s, keys.state, RobotState(position=(0, 0, 0), orientation=(0, 0, 0, 1), linear_velocity=(0, 0, 0),
                                          angular_velocity=(0, 0, 0)))
            for f in room_frames():
                n = len(grids.items)
                put(s, keys.perception_frame, f)
                grids.wait(n + 1, timeout_s=30)
            out, err = example.communicate(timeout=60)
        finally:
            if example.poll() is None:
                example.kill()
                example.communicate()
        assert example.returncode == 0, err + proc.output
        plan = json.loads(out)
        grid = next(g for g in grids.items if g.header.stamp_ns == plan["stamp_ns"])
        field = EsdfField.from_grid(grid, FilterConfig().interpolation)
        wps = np.array(plan["waypoints"])
        np.testing.assert_allclose(wps[0], [0.3, -0.2]) and np.testing.assert_allclose(wps[-1], [0.9, -1.2])
        assert (field.query(np.column_stack([wps, np.full(len(wps), 0.1)])).distance >= 0.1 - 1e-3).all()
        along = np.concatenate([a + np.linspace(0, 1, 50)[:, None] * (b - a) for a, b in itertools.pairwise(wps)])
        sample = field.query(np.column_stack([along, np.full(len(along), 0.1)]))
        assert sample.inside.all() and sample.distance.min() >= 0.1 - 0.01, sample.distance.min()
        assert plan["min_distance"] >= 0.1
        person = (0.8 <= along[:, 0]) & (along[:, 0] <= 1.0) & (-0.7 <= along[:, 1]) & (along[:, 1] <= -0.4)
        assert not person.any()
        goal = goals.wait(1, timeout_s=10)[0]
        np.testing.assert_allclose(goal.waypoints[-1], [0.9, -1.2, 0.0])
        goals.close()
        grids.close()
        assert proc.stop() == 0
