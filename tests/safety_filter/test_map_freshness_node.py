"""Map freshness by content, over a real Zenoh router with the filter (and mapping) in their own
processes: a stuck publisher replaying an old map, perception dead while
mapping re-emits, a replayed sequence number, a restarted mapper."""

from __future__ import annotations

import threading
import time

import numpy as np
import zenoh

from riskfield.protocol import (
    ENCODING,
    EsdfGrid,
    Keys,
    NodeStatus,
    PerceptionFrame,
    RiskConfig,
    RobotState,
    SafetyStatus,
    VelocityCommand,
    encode,
)
from riskfield.services.fields import AnalyticField, to_esdf, to_grid_message
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Plane, Sphere, render
from riskfield.services.geometry.transforms import orbit
from riskfield.services.runtime import Node, NodeSettings
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_until

GROUPS = ["high", "mid", "low"]
V_REF = 0.5


def wall(x: float) -> EsdfGrid:
    """A low-risk wall across the robot's path at ``x``: d = x − p_x."""
    plane = AnalyticField(Plane.through([x, 0.0, 0.0], [-1.0, 0.0, 0.0], label=3), groups=GROUPS)
    return to_grid_message(to_esdf(plane, [-1, -1, 0], [2, 1, 0], 0.05, planar=True))


def sphere(x: float) -> EsdfGrid:
    ball = AnalyticField(Sphere([x, 0.0, 0.0], 0.3, planar=True, label=1), groups=GROUPS)
    return to_grid_message(to_esdf(ball, [-1, -1, 0], [2, 1, 0], 0.05, planar=True))


def robot_state(x: float = 0.0) -> RobotState:
    return RobotState(position=(x, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0), linear_velocity=(0.0, 0.0, 0.0),
                      angular_velocity=(0.0, 0.0, 0.0))


class Inputs:
    """State and reference at 20 Hz (the robot stands at the origin and is asked to drive)."""

    def __init__(self, session: zenoh.Session, keys: Keys):
        self.session, self.keys = session, keys
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            put(self.session, self.keys.state, robot_state())
            put(self.session, self.keys.cmd_ref, VelocityCommand(linear=(V_REF, 0, 0), angular=(0, 0, 0),
                                                                 source="test"))
            time.sleep(0.05)

    def __enter__(self) -> Inputs:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2)


class MapPublisher:
    """Puts maps the way the runtime's ``Node.publish`` does: header seq and Zenoh source info
    (this publisher's entity id). Each instance is its own session, i.e. its own publisher."""

    def __init__(self, endpoint: str, keys: Keys):
        self._session_cm = client_session(endpoint)
        self.session = self._session_cm.__enter__()
        self.pub = self.session.declare_publisher(keys.esdf, encoding=zenoh.Encoding(ENCODING))

    def put(self, grid: EsdfGrid, seq: int, stamp_ns: int | None = None) -> None:
        g = grid.model_copy(deep=False)
        stamp = time.time_ns() if stamp_ns is None else stamp_ns
        g.header = g.header.model_copy(update={"seq": seq, "stamp_ns": stamp})
        self.pub.put(encode(g), source_info=zenoh.SourceInfo(self.pub.id, seq))

    def close(self) -> None:
        self.pub.undeclare()
        self._session_cm.__exit__(None, None, None)


def extra(status: Collector, name: str) -> float:
    return status.items[-1].extra.get(name, 0.0) if status.items else 0.0


def filter_process(endpoint: str, keys: Keys) -> ServiceProcess:
    return ServiceProcess("safety-filter", endpoint, ["--robot", keys.robot, "--set", "status_period_s=0.2"])


def test_a_stuck_publisher_replaying_an_old_free_map_is_never_followed(router_endpoint: str) -> None:
    """A fresh map with a wall 0.2 m ahead, and beside it a stuck publisher replaying (the same
    bytes, over and over) a 5-second-old map of free space: the old map is refused and reported,
    where following it would alternate cmd/safe between braking and the full 0.5 m/s."""
    keys = Keys("t_sf_stuck")
    old_free = wall(50.0)
    old_free.header.stamp_ns = time.time_ns() - 5_000_000_000
    stuck_bytes = encode(old_free)
    with filter_process(router_endpoint, keys) as proc, client_session(router_endpoint) as s, Inputs(s, keys):
        assert wait_alive(s, keys.alive("safety-filter")), proc.output
        status = Collector(s, keys.safety_status, SafetyStatus)
        node_status = Collector(s, keys.status("safety-filter"), NodeStatus)
        cmds = Collector(s, keys.cmd_safe, VelocityCommand)
        live = MapPublisher(router_endpoint, keys)
        stuck = Node("replay", NodeSettings(connect=[router_endpoint], robot=keys.robot))
        try:
            seq = 0

            def both() -> bool:
                nonlocal seq
                live.put(wall(0.45), seq)  # the look-ahead point is ~0.2 m from the wall
                stuck.publish_raw(keys.esdf, stuck_bytes)
                stuck.publish_raw(keys.esdf, stuck_bytes)
                seq += 1
                return extra(node_status, "map_refused_stale_map") >= 40

            assert wait_until(both, timeout_s=30, period_s=0.05), proc.output
            moving = [c.linear[0] for c in cmds.items if c.source == "safety-filter/test"]
            assert moving, "the filter never filtered on the live map"
            assert max(moving) < 0.45 * V_REF + 0.2, moving  # the wall holds it back; free space would give 0.5
            assert max(st.esdf_publishers for st in status.items) == 2
            assert max(st.esdf_refused for st in status.items) >= 40
            assert "refused an ESDF (stale_map" in proc.output
        finally:
            live.close()
            stuck.close()
        for c in (status, node_status, cmds):
            c.close()
        assert proc.stop() == 0, proc.output


def test_seq_backwards_is_refused_and_a_restarted_mapper_is_accepted(router_endpoint: str) -> None:
    keys = Keys("t_sf_seq")
    near, far = sphere(0.6), sphere(1.6)
    with filter_process(router_endpoint, keys) as proc, client_session(router_endpoint) as s, Inputs(s, keys):
        assert wait_alive(s, keys.alive("safety-filter")), proc.output
        status = Collector(s, keys.safety_status, SafetyStatus)
        node_status = Collector(s, keys.status("safety-filter"), NodeStatus)
        mapper = MapPublisher(router_endpoint, keys)
        h_near = h_far = None
        try:
            seq = 10

            def on(grid: EsdfGrid, pub: MapPublisher, seq_of, until) -> None:
                def step() -> bool:
                    pub.put(grid, seq_of())
                    return until()
                assert wait_until(step, timeout_s=20, period_s=0.05), proc.output

            def up() -> int:
                nonlocal seq
                seq += 1
                return seq

            def settled_h() -> float | None:
                last = status.items[-1] if status.items else None
                return None if last is None or last.fallback is not None else last.h

            on(near, mapper, up, lambda: settled_h() is not None)
            h_near = settled_h()
            # the same publisher goes back to seq 3 with another map: refused, the near map stays in force
            refused0 = extra(node_status, "map_refused_seq_backwards")
            on(far, mapper, lambda: 3, lambda: extra(node_status, "map_refused_seq_backwards") >= refused0 + 5)
            n = len(status.items)
            assert wait_until(lambda: len(status.items) > n + 2, 5)
            assert all(st.h == h_near or st.fallback == "stale_map" for st in status.items[n:])
            # the mapper restarts: a new session, seq from 0 again, and its map is taken
            mapper.close()
            mapper = MapPublisher(router_endpoint, keys)
            restarted = iter(range(1000))
            on(far, mapper, lambda: next(restarted), lambda: (settled_h() or 0.0) > h_near + 0.5)
            h_far = settled_h()
        finally:
            mapper.close()
        assert h_near is not None and h_far is not None and h_far > h_near
        status.close()
        node_status.close()
        assert proc.stop() == 0, proc.output


# -- perception dead, mapping alive: re-emits must not look fresh ----------------------------------


def frames(n: int) -> list[PerceptionFrame]:
    from riskfield.protocol import ade20k

    cam = PinholeCamera.centred(160, 120, 125.0)
    scene = [Plane((1, 0, 0), 1.5, ade20k.index("wall")), Plane((0, 0, 1), 0.0, ade20k.index("floor"))]
    out = []
    for i, T in enumerate(orbit([1.2, 0.0, 0.3], n=n, radius=0.2, height=0.3)):
        pts, conf, lab = render(scene, T, cam)
        out.append(PerceptionFrame(T_WC=T, points=pts, confidence=conf, labels=lab, keyframe_id=i))
    return out


def test_perception_dead_brakes_with_stale_map_although_mapping_re_emits(router_endpoint: str) -> None:
    """Mapping re-publishes its last ESDF on every risk-config change; with no new frame the
    ESDF keeps the last frame's stamp, and the filter brakes with ``stale_map`` once that
    content is older than map_timeout_s + clock_tolerance_s (0.3 + 0.1 s), reporting the
    content age. Before, it reported an ESDF age of a few ms and kept driving."""
    keys = Keys("t_sf_dead")
    with (ServiceProcess("mapping", router_endpoint, ["--robot", keys.robot, "--set", "esdf_rate_hz=20"]) as mapping,
          filter_process(router_endpoint, keys) as filt,
          client_session(router_endpoint) as s, Inputs(s, keys)):
        assert wait_alive(s, keys.alive("mapping"), 60) and wait_alive(s, keys.alive("safety-filter")), \
            mapping.output + filt.output
        grids = Collector(s, keys.esdf, EsdfGrid)
        status = Collector(s, keys.safety_status, SafetyStatus)
        pending = frames(6)
        last_stamp = 0

        def perceive() -> bool:  # live perception: frames until the filter works on the map
            nonlocal last_stamp
            f = pending[len(grids.items) % len(pending)]
            f.header.stamp_ns = last_stamp = time.time_ns()
            put(s, keys.perception_frame, f)
            st = status.items[-1] if status.items else None
            return st is not None and (st.fallback is None or not st.fallback.endswith("_map"))

        assert wait_until(perceive, timeout_s=90, period_s=0.15), mapping.output + filt.output
        # perception dies; the risk configuration changes every 50 ms, so mapping keeps re-emitting
        assert wait_until(lambda: grids.items and grids.items[-1].header.stamp_ns == last_stamp, 10)
        n_grids, n_status = len(grids.items), len(status.items)
        margins = iter(np.tile([0.15, 0.20], 1000))

        def re_emit() -> bool:
            risk = RiskConfig()
            risk.groups[0].margin = float(next(margins))
            put(s, keys.risk_config, risk)
            stale = [st for st in status.items[n_status:] if st.fallback == "stale_map"]
            return len(grids.items) >= n_grids + 3 and bool(stale)

        assert wait_until(re_emit, timeout_s=20, period_s=0.05), filt.output
        re_emitted = grids.items[n_grids:]
        assert all(g.header.stamp_ns == last_stamp for g in re_emitted)  # the stamp of the newest frame
        assert [g.header.seq for g in re_emitted] == sorted({g.header.seq for g in re_emitted})
        first_stale = next(st for st in status.items[n_status:] if st.fallback == "stale_map")
        # The content age, not the arrival's (a few ms): past the timeout and tolerance, and no
        # older than the newest frame is now (one wall clock: no bound on how late the status came).
        assert 400.0 < first_stale.esdf_age_ms <= (time.time_ns() - last_stamp) / 1e6, first_stale
        grids.close()
        status.close()
        assert filt.stop() == 0, filt.output
        assert mapping.stop() == 0, mapping.output
