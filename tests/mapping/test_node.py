"""The mapping node in its own process over a real Zenoh router: publishes, answers, survives bad input."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import msgpack
import numpy as np
import pytest
import yaml
import zenoh

from riskfield.protocol import (
    ENCODING,
    DistanceQuery,
    DistanceReply,
    EsdfGrid,
    Header,
    Keys,
    NodeStatus,
    PerceptionFrame,
    RiskConfig,
    RobotState,
    VelocityCommand,
    ade20k,
    decode,
    encode,
    to_map,
)
from riskfield.services.fields import EsdfField, answer_query
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Plane, render
from riskfield.services.geometry.transforms import look_at, orbit
from riskfield.services.mapping.config import MapperConfig
from riskfield.testing import Collector, ServiceProcess, StatusWatch, client_session, put, wait_alive, wait_until

CAM = PinholeCamera.centred(160, 120, 125.0)


def room() -> list:
    from riskfield.protocol import ade20k

    return [Plane((1, 0, 0), 1.5, ade20k.index("wall")), Plane((0, 0, 1), 0.0, ade20k.index("floor")),
            Box((0.8, -0.7, 0.0), (1.0, -0.4, 1.2), ade20k.index("person"))]


def frames(n: int = 4) -> list[PerceptionFrame]:
    out = []
    for i, T in enumerate(orbit([1.2, 0.0, 0.3], n=n, radius=0.2, height=0.3)):
        pts, conf, lab = render(room(), T, CAM)
        out.append(PerceptionFrame(T_WC=T, points=pts, confidence=conf, labels=lab, keyframe_id=i))
    return out


def state() -> RobotState:
    return RobotState(position=(0, 0, 0), orientation=(0, 0, 0, 1), linear_velocity=(0, 0, 0),
                      angular_velocity=(0, 0, 0))


def query(session: zenoh.Session, key: str, payload: bytes, timeout: float = 5.0) -> list[zenoh.Reply]:
    return list(session.get(key, payload=payload, encoding=zenoh.Encoding(ENCODING), timeout=timeout))


def ask(session: zenoh.Session, keys: Keys, points: np.ndarray) -> DistanceReply:
    replies = query(session, keys.esdf_query, encode(DistanceQuery(points=points)))
    oks = [r.ok for r in replies if r.ok is not None]
    assert oks, f"no reply ({[r.err.payload.to_bytes() for r in replies if r.err is not None]})"
    return decode(oks[0].payload.to_bytes(), DistanceReply)


def ready(session: zenoh.Session, keys: Keys, timeout_s: float = 30.0) -> bool:
    """Liveliness comes up before the node has warmed its kernels and declared its queryable."""
    payload = encode(DistanceQuery(points=np.zeros((1, 3))))
    return wait_until(lambda: any(r.ok is not None for r in query(session, keys.esdf_query, payload, 0.5)),
                      timeout_s, 0.1)


def feed(session: zenoh.Session, keys: Keys, msgs: list[PerceptionFrame], grids: Collector) -> None:
    put(session, keys.state, state())
    for f in msgs:
        n = len(grids.items)
        put(session, keys.perception_frame, f)
        grids.wait(n + 1)  # the frame queue keeps only the newest: the next goes once this one is in the map


IN_FRONT = np.array([[0.5, -0.55, 0.3], [0.6, -0.55, 0.3]])


def test_node_publishes_slice_and_3d_grid_and_answers_queries(router_endpoint: str) -> None:
    keys = Keys("t_map_pub")
    args = ["--robot", keys.robot, "--set", "output=both", "--set", "esdf_rate_hz=20", "--set", "status_period_s=0.05"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")) and ready(s, keys), proc.output
        grids, grids3d = Collector(s, keys.esdf, EsdfGrid), Collector(s, keys.key("map/esdf3d"), EsdfGrid)
        status = StatusWatch(s, keys.status("mapping"))
        # before any frame: nothing published, queries say "outside the map"
        early = ask(s, keys, IN_FRONT)
        assert early.in_map is not None and not early.in_map.any()
        assert np.all(early.distance == 2.0)
        assert not grids.items
        feed(s, keys, frames(), grids)
        g = grids.wait(1)[-1]
        g3 = grids3d.wait(1)[-1]
        shape = MapperConfig().shape  # the node's defaults
        assert g.shape == (*shape[:2], 1) and g3.shape == shape
        assert g.groups == ["high", "mid", "low"] and g.max_distance == 2.0 and not g.unknown_is_occupied
        assert np.isfinite(g.distance).all() and (g.distance < 0).any() and (g.risk_group == 1).any()
        assert g.header.stamp_ns > 0
        reply = ask(s, keys, IN_FRONT)
        true = 0.8 - IN_FRONT[:, 0] - 0.15
        assert reply.in_map is not None and reply.in_map.all()
        assert np.all(reply.risk_group == 1)
        assert np.all(np.abs(reply.distance - true) <= 0.075)
        assert np.all(reply.gradient[:, 0] < -0.5)
        # No new data: no new grids (the filter must see the map age). The node's own status, on
        # the loop thread its ESDF timer runs on, shows 8 ESDF periods of its uptime passing with
        # nothing published: proof that the loop ran, not that it stalled. Statuses and grids leave
        # the node's session in order, so a grid published before that status has arrived by then.
        first = status.wait(lambda st: st.published.get("map/esdf", 0) >= len(grids.items))
        published = first.published["map/esdf"]
        later = status.wait(lambda st: st.uptime_s >= first.uptime_s + 0.4)
        assert later.published.get("map/esdf") == published == len(grids.items)
        status.close()
        grids.close()
        grids3d.close()
        assert proc.stop() == 0


def frame_map(f: PerceptionFrame) -> dict:
    return to_map(f)


def bad_payloads() -> dict[str, list[bytes]]:
    """Malformed input for every key the node listens on."""
    good = frames(1)[0]
    m = frame_map(good)
    truncated = encode(good)[: len(encode(good)) // 2]
    nan_pose = dict(m, T_WC=dict(m["T_WC"], data=np.full((4, 4), np.nan).tobytes()))
    f64_points = dict(m, points={"dtype": "<f8", "shape": list(good.points.shape),
                                 "data": good.points.astype("<f8").tobytes()})
    giant = dict(m, points={"dtype": "<f4", "shape": [100000, 100000, 3], "data": b"\0" * 12})
    mismatch = dict(m, confidence=dict(m["confidence"], shape=[60, 160], data=good.confidence[:60].tobytes()))
    scaled = good.T_WC.copy()
    scaled[:3, :3] *= 1.5  # valid message, but not a rigid pose: rejected by the core
    big_frame = {"dtype": "<f4", "shape": [2100, 2100, 3], "data": b"\0" * (2100 * 2100 * 12)}
    vc = encode(VelocityCommand.zero("fuzz"))
    st = to_map(state())
    risk = to_map(RiskConfig())
    rng = np.random.default_rng(1)
    junk = [bytes(rng.integers(0, 256, n, dtype=np.uint8)) for n in (0, 1, 7, 300)]
    return {
        "frame": [*junk, truncated, vc, msgpack.packb(nan_pose), msgpack.packb(f64_points), msgpack.packb(giant),
                  msgpack.packb(mismatch), encode(good.model_copy(update={"T_WC": scaled})),
                  msgpack.packb(dict(m, points=big_frame)), msgpack.packb([1, 2, 3])],
        "state": [*junk, vc, msgpack.packb(dict(st, position=[float("nan"), 0.0, 0.0])),
                  msgpack.packb(dict(st, orientation=[0, 0, 0, 2.0])), msgpack.packb(dict(st, position="x"))],
        "risk": [*junk, vc, msgpack.packb(dict(risk, groups=[])), msgpack.packb(dict(risk, default_group="nope"))],
        "query": [*junk, vc, msgpack.packb({"schema": "DistanceQuery/1", "header": {},
                                            "points": {"dtype": "<f8", "shape": [2, 3],
                                                       "data": np.array([[np.nan] * 3] * 2).tobytes()}}),
                  msgpack.packb({"schema": "DistanceQuery/1", "header": {},
                                 "points": {"dtype": "<f4", "shape": [1, 3], "data": b"\0" * 12}}),
                  msgpack.packb({"schema": "DistanceQuery/1", "header": {},
                                 "points": {"dtype": "<f8", "shape": [10**8, 3], "data": b""}})],
    }


def test_node_rejects_bad_input_on_every_key_and_keeps_serving(router_endpoint: str) -> None:
    keys = Keys("t_map_fuzz")
    args = ["--robot", keys.robot, "--set", "esdf_rate_hz=20", "--set", "status_period_s=0.3"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")) and ready(s, keys), proc.output
        grids = Collector(s, keys.esdf, EsdfGrid)
        status = Collector(s, keys.status("mapping"), NodeStatus)
        bad = bad_payloads()
        for key, name in ((keys.perception_frame, "frame"), (keys.state, "state"), (keys.risk_config, "risk")):
            for payload in bad[name]:
                put(s, key, payload)
                ask(s, keys, IN_FRONT)  # served by the same loop after the put: the payload has been handled
        for payload in bad["query"]:
            replies = query(s, keys.esdf_query, payload)
            assert replies and all(r.ok is None for r in replies), "a bad query must get an error reply"
        # A map made of bad frames would go out at the next ESDF tick (20 Hz): two status periods later, none did.
        n_status = len(status.items)
        assert wait_until(lambda: len(status.items) >= n_status + 2, 5.0), proc.output
        assert proc.alive(), proc.output
        assert not grids.items, "no map may come out of bad frames"
        # it still serves: a valid frame makes a valid map, a valid query gets an answer
        feed(s, keys, frames(2), grids)
        g = grids.wait(1)[-1]
        assert np.isfinite(g.distance).all() and (g.distance < 0).any()
        reply = ask(s, keys, IN_FRONT)
        assert reply.in_map is not None and reply.in_map.all() and np.all(reply.risk_group == 1)

        def counted() -> bool:
            # every bad payload arrived and was rejected (or overwritten by the next in the latest-value queue)
            if not status.items:
                return False
            st = status.items[-1]
            ok = True
            for key, name in (("perception/frame", "frame"), ("state", "state"), ("config/risk", "risk")):
                handled = st.invalid.get(key, 0) + st.dropped.get(key, 0)
                if key == "perception/frame":
                    handled += int(st.extra.get("rejected_frames", 0))
                ok &= st.received.get(key, 0) >= len(bad[name]) and handled >= len(bad[name]) - 1
                ok &= st.invalid.get(key, 0) >= 3
            return ok and st.invalid.get("map/esdf/query", 0) == len(bad["query"])

        assert wait_until(counted, 5.0), repr(status.items[-1]) if status.items else "no status"
        assert status.items[-1].errors == 0, proc.output
        assert "rejected a message on" in proc.output
        assert "rejected a perception frame: T_WC rotation is not orthonormal" in proc.output
        grids.close()
        status.close()
        assert proc.stop() == 0


def test_risk_config_hot_reload_from_key_and_file(router_endpoint: str, tmp_path: Path) -> None:
    keys = Keys("t_map_risk")
    risk_file = tmp_path / "risk.yaml"
    cfg = RiskConfig()
    risk_file.write_text(yaml.safe_dump(cfg.model_dump(exclude={"header"})))
    args = ["--robot", keys.robot, "--set", "esdf_rate_hz=20", "--set", f"risk_file={risk_file}",
            "--set", "risk_poll_s=0.2"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")) and ready(s, keys), proc.output
        grids = Collector(s, keys.esdf, EsdfGrid)
        feed(s, keys, frames(3), grids)
        grids.wait(1)
        d0 = ask(s, keys, IN_FRONT).distance
        # over the key: the high-risk margin grows by 0.25 m
        wider = RiskConfig()
        wider.groups[0].margin = 0.40
        n = len(grids.items)
        put(s, keys.risk_config, wider)
        grids.wait(n + 1)
        d1 = ask(s, keys, IN_FRONT).distance
        assert np.allclose(d0 - d1, 0.25, atol=1e-5)
        # through the file: margin 0.05
        narrow = RiskConfig()
        narrow.groups[0].margin = 0.05
        n = len(grids.items)
        # The same size as the last write: the watcher sees it by a later modification time, set
        # here rather than waited for (the file system's clock resolution).
        before = risk_file.stat().st_mtime_ns
        risk_file.write_text(yaml.safe_dump(narrow.model_dump(exclude={"header"})))
        os.utime(risk_file, ns=(before + 10**9, before + 10**9))
        grids.wait(n + 1)
        d2 = ask(s, keys, IN_FRONT).distance
        assert np.allclose(d0 - d2, -0.10, atol=1e-5)
        # a broken file is reported, counted and ignored
        status = Collector(s, keys.status("mapping"), NodeStatus)
        risk_file.write_text("groups: [")
        assert wait_until(lambda: status.items and status.items[-1].extra.get("risk_errors") == 1, 10)
        assert np.allclose(ask(s, keys, IN_FRONT).distance, d2, atol=1e-6)
        assert "not loaded" in proc.output
        status.close()
        grids.close()
        assert proc.stop() == 0


@pytest.mark.parametrize("value", ["band=[1,0]", "voxel_size=-1", "output=4d"])
def test_bad_settings_fail_fast_with_a_clear_message(router_endpoint: str, value: str) -> None:
    with ServiceProcess("mapping", router_endpoint, ["--robot", "t_map_bad", "--set", value]) as proc:
        assert proc.proc is not None
        proc.proc.wait(30)
        assert proc.proc.returncode == 2
        assert "invalid configuration for mapping" in proc.output


def test_node_follows_the_keyframe_protocol_without_dropping_updates(router_endpoint: str) -> None:
    """A burst of new keyframes, a re-posed keyframe and tracking frames, sent back to back: the FIFO
    keeps every one, the update replaces its keyframe's contribution, the tracked frame reaches the map."""
    keys = Keys("t_map_kf")
    args = ["--robot", keys.robot, "--set", "esdf_rate_hz=20", "--set", "status_period_s=0.2"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")) and ready(s, keys), proc.output
        status = Collector(s, keys.status("mapping"), NodeStatus)
        grids = Collector(s, keys.esdf, EsdfGrid)
        put(s, keys.state, state())
        kfs = frames(4)
        moved = kfs[3].T_WC.copy()
        moved[:3, 3] += (0.3, 0.2, 0.0)
        burst = [f.model_copy(update={"kind": "keyframe_new"}) for f in kfs[:3]]
        burst.append(kfs[3].model_copy(update={"kind": "keyframe_new", "T_WC": moved}))  # drifted
        burst.append(kfs[3].model_copy(update={"kind": "keyframe_update"}))  # the loop closure
        burst.append(kfs[0].model_copy(update={"kind": "tracking", "header": kfs[0].header.model_copy(
            update={"stamp_ns": 123456789})}))
        for f in burst:  # no pause: a "latest" queue would drop most of them
            put(s, keys.perception_frame, f)

        def counted() -> bool:
            ex = status.items[-1].extra if status.items else {}
            return ex.get("kf_keyframe_new") == 4 and ex.get("kf_keyframe_update") == 1 and ex.get("kf_tracking") == 1

        assert wait_until(counted, 20), status.items[-1].extra if status.items else proc.output
        assert status.items[-1].extra["frames"] == 6  # four new, one update and the tracked frame integrated
        assert wait_until(lambda: any(g.header.stamp_ns == 123456789 for g in grids.items), 10)
        reply = ask(s, keys, IN_FRONT)  # the person is where the corrected keyframes put it
        assert np.all(np.abs(reply.distance - (0.8 - IN_FRONT[:, 0] - 0.15)) <= 0.075)
        status.close()
        grids.close()
        assert proc.stop() == 0


@contextlib.contextmanager
def plain_burst(router_endpoint: str, robot: str, msgs: list[PerceptionFrame],
                first_stamp: int) -> Iterator[tuple[ServiceProcess, Collector, Collector, list[PerceptionFrame]]]:
    """A mapping node (status every 0.2 s) sent ``msgs`` back to back, outside the keyframe
    protocol, stamped ``first_stamp``, +1, …: yields the process, its status and ESDF collectors and
    the frames as sent; the node must stop cleanly after."""
    keys = Keys(robot)
    args = ["--robot", robot, "--set", "esdf_rate_hz=100", "--set", "status_period_s=0.2"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")) and ready(s, keys), proc.output
        status = Collector(s, keys.status("mapping"), NodeStatus)
        grids = Collector(s, keys.esdf, EsdfGrid)
        put(s, keys.state, state())
        sent = [f.model_copy(update={"header": f.header.model_copy(update={"stamp_ns": first_stamp + i})})
                for i, f in enumerate(msgs)]
        for f in sent:
            put(s, keys.perception_frame, f)
        try:
            yield proc, status, grids, sent
        finally:
            status.close()
            grids.close()
        assert proc.stop() == 0


def test_a_pair_of_frames_back_to_back_both_reach_the_map(router_endpoint: str) -> None:
    """``frame_backlog = 1`` (the default): two plain frames sent back to back are both integrated
    and both get an ESDF, whichever way their arrival interleaves with the handling of the first
    (the one ahead never has more than one newer frame behind it)."""
    with plain_burst(router_endpoint, "t_map_pair", frames(2), 2_000_000) as (proc, status, grids, pair):
        stamps = {f.header.stamp_ns for f in pair}
        assert wait_until(lambda: stamps <= {g.header.stamp_ns for g in grids.items}, 20), proc.output
        assert wait_until(lambda: bool(status.items) and status.items[-1].extra.get("frames") == 2, 10)
        assert "superseded_frames" not in status.items[-1].extra


def test_plain_frames_keep_latest_value_semantics_behind_the_fifo(router_endpoint: str) -> None:
    """Frames outside the keyframe protocol (no ``kind``) sent back to back: each is integrated or
    skipped as superseded by newer ones waiting behind it, never both and never lost, and the
    newest one always reaches the map (its stamp is the ESDF's)."""
    with plain_burst(router_endpoint, "t_map_latest", frames(4) * 2, 1_000_000) as (proc, status, grids, burst):

        def settled() -> bool:
            ex = status.items[-1].extra if status.items else {}
            return ex.get("frames", 0) + ex.get("superseded_frames", 0) == len(burst)

        assert wait_until(settled, 20), status.items[-1].extra if status.items else proc.output
        newest = burst[-1].header.stamp_ns
        assert wait_until(lambda: any(g.header.stamp_ns == newest for g in grids.items), 10)


# -- the map shows the present (issue 23) ------------------------------------------------------------

NOW_ROOM = [Plane((1, 0, 0), 2.5, ade20k.index("wall")), Plane((0, 0, 1), 0.0, ade20k.index("floor"))]
NOW_PERSON = Box((1.5, -0.2, 0.0), (1.8, 0.2, 1.7), ade20k.index("person"))
NOW_T = look_at(np.array([0.0, 0.0, 0.3]), np.array([2.0, 0.0, 0.3]))
NOW_PROBE = np.array([[1.3, 0.0, 0.3]])  # 0.2 m in front of the person's face: inside the 0.15 m margin
STEP_NS = 100_000_000  # 10 Hz


def field_at(grid: EsdfGrid, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sample = answer_query(EsdfField.from_grid(grid), points)
    return sample.distance, sample.risk_group


def shows_person(grid: EsdfGrid) -> bool:
    d, g = field_at(grid, NOW_PROBE)
    return bool(d[0] < 0.1 and g[0] == 1)


def send_and_wait(s: zenoh.Session, keys: Keys, grids: Collector, f: PerceptionFrame) -> EsdfGrid:
    """Send one frame (10 Hz camera: the next waits for this one's map) and return the first ESDF
    stamped at or after it."""
    stamp = f.header.stamp_ns
    put(s, keys.perception_frame, f)
    assert wait_until(lambda: any(g.header.stamp_ns >= stamp for g in grids.items), 20)
    return next(g for g in grids.items if g.header.stamp_ns >= stamp)


def now_frame(scene: list, stamp: int, q: float, kind: str | None) -> PerceptionFrame:
    pts, conf, lab = render(scene, NOW_T, CAM, confidence=q)
    return PerceptionFrame(header=Header(stamp_ns=stamp), T_WC=NOW_T, points=pts, confidence=conf, labels=lab,
                           keyframe_id=0, kind=kind, intrinsics=(CAM.fx, CAM.fy, CAM.cx, CAM.cy))


def test_tracked_frames_show_a_new_object_by_the_third_and_its_ghost_clears(router_endpoint: str) -> None:
    """Keyframe protocol: one ``keyframe_new`` of an empty room, then ``tracking`` frames in which a
    person stands 1.5 m ahead (confidence 7, the ``sim`` backend's for a fresh keyframe): the first
    ESDF stamped at or after the third shows them; once they left, the space clears within 1 s of
    frames while the camera does not move (no new keyframe)."""
    keys = Keys("t_map_now_kf")
    args = ["--robot", keys.robot, "--set", "esdf_rate_hz=20"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")) and ready(s, keys), proc.output
        grids = Collector(s, keys.esdf, EsdfGrid)
        put(s, keys.state, state())
        t = 1_000_000_000
        g = send_and_wait(s, keys, grids, now_frame(NOW_ROOM, t, 10.0, "keyframe_new"))
        assert not shows_person(g)
        for i in range(1, 4):
            g = send_and_wait(s, keys, grids, now_frame([*NOW_ROOM, NOW_PERSON], t + i * STEP_NS, 7.0, "tracking"))
        assert g.header.stamp_ns == t + 3 * STEP_NS and shows_person(g), field_at(g, NOW_PROBE)
        for _ in range(7):  # the person stands 0.7 s more
            t += STEP_NS
            send_and_wait(s, keys, grids, now_frame([*NOW_ROOM, NOW_PERSON], t + 3 * STEP_NS, 7.0, "tracking"))
        cleared = None
        for i in range(1, 11):
            g = send_and_wait(s, keys, grids, now_frame(NOW_ROOM, t + (3 + i) * STEP_NS, 7.0, "tracking"))
            if field_at(g, NOW_PROBE)[0][0] > 0.5:
                cleared = i
                break
        assert cleared is not None and cleared <= 10, proc.output  # within 1 s at 10 Hz
        grids.close()
        assert proc.stop() == 0


def test_default_perception_mode_shows_an_object_appearing_between_keyframes(router_endpoint: str) -> None:
    """The ``sim`` backend in its default mode (``publish = keyframe``, degraded pointmaps) feeds
    the node: a person who steps in after the keyframe started (the frames keep its id) is in the
    first ESDF stamped at or after the third frame that shows them."""
    from riskfield.services.perception.sim_backend import SimBackend

    backend = SimBackend()
    keys = Keys("t_map_now_default")
    args = ["--robot", keys.robot, "--set", "esdf_rate_hz=20"]

    def perceive(scene: list, stamp: int) -> PerceptionFrame:
        pts, conf, lab = render(scene, NOW_T, CAM)
        truth = PerceptionFrame(header=Header(stamp_ns=stamp), T_WC=NOW_T, points=pts, confidence=conf, labels=lab,
                                keyframe_id=0)
        (f,) = backend.process(None, truth, stamp)
        assert f.kind is None and f.keyframe_id == 0  # the default mode, one keyframe throughout
        return f

    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")) and ready(s, keys), proc.output
        grids = Collector(s, keys.esdf, EsdfGrid)
        put(s, keys.state, state())
        t = 1_000_000_000
        for i in range(10):
            g = send_and_wait(s, keys, grids, perceive(NOW_ROOM, t + i * STEP_NS))
        assert not shows_person(g)
        t += 10 * STEP_NS
        for i in range(3):
            g = send_and_wait(s, keys, grids, perceive([*NOW_ROOM, NOW_PERSON], t + i * STEP_NS))
        assert g.header.stamp_ns == t + 2 * STEP_NS and shows_person(g), field_at(g, NOW_PROBE)
        grids.close()
        assert proc.stop() == 0
