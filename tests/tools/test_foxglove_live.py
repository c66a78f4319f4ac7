"""The live Foxglove view: the scene views (tracked objects, robot footprint), the shipped layout, and
the ``foxglove`` node serving a live stack to a real WebSocket client speaking the Foxglove
WebSocket protocol (github.com/foxglove/ws-protocol, docs/spec.md: ``serverInfo`` and ``advertise``
as JSON text, the client's ``subscribe``, then binary Message Data: opcode 0x01, uint32 id, uint64
log time, payload, little-endian). The SDK's server (foxglove/foxglove-sdk,
rust/foxglove/src/websocket/handshake.rs ``SUBPROTOCOL``) accepts only the subprotocol
``foxglove.sdk.v1``, the successor of the spec's ``foxglove.websocket.v1`` that current Foxglove
offers, and answers ``foxglove.websocket.v1`` alone with HTTP 400; its Message Data carries the
channel id where the spec has the subscription id (ws_protocol/server/message_data.rs), so the
client subscribes with subscription id = channel id and reads either."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import websockets.sync.client  # the dev extra has it (as foxglove): missing is a broken environment, not a skip
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Grid_pb2 import Grid
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneEntityDeletion_pb2 import SceneEntityDeletion
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from hypothesis import given
from hypothesis import strategies as st

from riskfield.protocol import (
    EsdfGrid,
    Header,
    Image,
    Keys,
    PerceptionFrame,
    RobotState,
    SafetyStatus,
    TrackedObject,
    TrackedObjects,
    VelocityCommand,
    ade20k,
)
from riskfield.services.recorder.live import LAYOUT, layout
from riskfield.services.recorder.views import objects_view, robot_view
from riskfield.testing import ServiceProcess, StatusWatch, client_session, put, wait_alive

PROTO = {c.DESCRIPTOR.full_name: c for c in (CompressedImage, FrameTransform, Grid, PointCloud, PoseInFrame,
                                              SceneUpdate)}


def rotate(q, v) -> np.ndarray:
    x, y, z, w = q
    u = np.array([x, y, z])
    return 2 * np.dot(u, v) * u + (w * w - np.dot(u, u)) * np.asarray(v) + 2 * w * np.cross(u, v)


def people(stamp_ns: int = 5) -> TrackedObjects:
    return TrackedObjects(header=Header(stamp_ns=stamp_ns), objects=[
        TrackedObject(id=3, label=ade20k.index("person"), risk_group=1, position=(1.0, -0.5, 0.8),
                      velocity=(0.0, 1.2, 0.0), radius=0.25, age_ms=0.0),
        TrackedObject(id=7, label=ade20k.index("animal"), risk_group=1, position=(2.0, 0.5, 0.3),
                      velocity=(0.0, 0.0, 0.0), radius=0.3, age_ms=40.0)])


@given(st.tuples(*[st.floats(-3, 3)] * 3).filter(lambda v: np.linalg.norm(v) > 0.01))
def test_velocity_arrows_point_along_the_velocity(v):
    m = TrackedObjects(objects=[TrackedObject(id=1, label=12, risk_group=1, position=(0, 0, 0), velocity=v,
                                              radius=0.2, age_ms=0)])
    (view,) = objects_view("t/map/objects", m)
    (arrow,) = SceneUpdate.FromString(view.data).entities[0].arrows
    o = arrow.pose.orientation
    np.testing.assert_allclose(rotate((o.x, o.y, o.z, o.w), [1.0, 0, 0]), np.array(v) / np.linalg.norm(v), atol=1e-9)
    assert arrow.shaft_length == pytest.approx(np.linalg.norm(v))


def test_objects_view_replaces_every_entity_and_labels_each_object():
    (view,) = objects_view("t/map/objects", people())
    up = SceneUpdate.FromString(view.data)
    assert view.schema == "foxglove.SceneUpdate" and [d.type for d in up.deletions] == [SceneEntityDeletion.ALL]
    assert [e.id for e in up.entities] == ["object/3", "object/7"]
    person, dog = up.entities
    assert person.cylinders[0].size.x == pytest.approx(0.5) and person.cylinders[0].color.r > 0.8  # high: red
    assert len(person.arrows) == 1 and not dog.arrows  # a static object has no arrow
    assert person.texts[0].text == "person #3 (high) 1.20 m/s"
    assert {kv.key: kv.value for kv in dog.metadata} == {"class": "animal", "risk_group": "high"}
    (empty,) = objects_view("t/map/objects", TrackedObjects())
    gone = SceneUpdate.FromString(empty.data)
    assert not gone.entities and len(gone.deletions) == 1  # the last person left: the old ones go


def test_robot_view_says_what_the_filter_does_and_why():
    state = RobotState(position=(1, 2, 0), orientation=(0, 0, 0, 1), linear_velocity=(0, 0, 0),
                       angular_velocity=(0, 0, 0))

    def text(status, body=(0.322, 0.22)):
        (view,) = robot_view("t/robot", state, body, status)
        e = SceneUpdate.FromString(view.data).entities[0]
        shape = e.cubes[0] if isinstance(body, tuple) else e.cylinders[0]
        assert shape.pose.position.y == 2
        return e.texts[0].text, (shape.color.r, shape.color.g), (shape.size.x, shape.size.y)

    base = dict(h=0.3, risk_group=1, solve_us=1.0, esdf_age_ms=5.0)
    assert text(None)[0] == "no safety status"
    passing, green, size = text(SafetyStatus(intervening=False, fallback=None, **base))
    assert passing == "passing (h = 0.30 m)" and green[1] > green[0]
    assert size == pytest.approx((0.322, 0.22))  # the LIMO's body, as the filter protects it
    assert text(SafetyStatus(intervening=True, fallback=None, **base), 0.2)[2] == pytest.approx((0.4, 0.4))
    assert text(SafetyStatus(intervening=True, fallback=None, **base))[0] == "intervening (h = 0.30 m)"
    why = SafetyStatus(intervening=True, fallback=None, yielding=True, speed_cap=0.25, scale_uncertain=True, **base)
    assert text(why)[0] == ("intervening (h = 0.30 m, yielding to someone moving, speed cap 0.25 m/s, "
                            "map scale uncertain)")
    braking, red, _ = text(SafetyStatus(intervening=True, fallback="stale_map", **base))
    assert braking == "braking: stale_map" and red[0] > red[1]


def test_the_live_view_draws_the_platforms_body():
    from riskfield.protocol.platforms import LIMO
    from riskfield.services.recorder.live import FoxgloveSettings

    assert FoxgloveSettings().body == (LIMO.length, LIMO.width)
    assert FoxgloveSettings(platform="multicopter", robot_radius=0.3).body == 0.3
    with pytest.raises(ValueError, match="unknown platform 'limp'"):
        FoxgloveSettings(platform="limp")


def test_the_shipped_layout_is_the_generated_one_and_names_the_live_topics():
    shipped = json.loads(LAYOUT.read_text())
    assert shipped == layout("rf/limo1"), "regenerate: python -c 'from riskfield.services.recorder.live import ...'"
    text = json.dumps(shipped)
    for topic in ("map/esdf", "perception/frame", "robot", "map/objects", "camera/image", "safety/status"):
        assert f"rf/limo1/{topic}" in text


def test_the_demo_serves_foxglove_for_its_own_robot_and_says_where(tmp_path):
    """``riskfield demo --foxglove``: the demo's router is on a free port and its robot is not limo1, so
    the demo runs the foxglove service on its own router and writes the layout of its own robot."""
    import io

    from rich.console import Console

    from riskfield.experiments.demo.run import Demo, DemoConfig

    said = io.StringIO()
    demo = Demo(DemoConfig(out=tmp_path, foxglove=True), console=Console(file=said, width=400))
    runner = demo._runner()
    try:
        argv = runner.children["foxglove"].argv
        assert argv[argv.index("--connect") + 1] == demo.endpoint and argv[argv.index("--robot") + 1] == "demo1"
        assert "foxglove" not in Demo(DemoConfig(out=tmp_path), console=Console(file=io.StringIO()))._runner().children
    finally:
        runner.close()
    demo._how_to_watch()
    assert json.loads((tmp_path / "foxglove-layout.json").read_text()) == layout("rf/demo1")
    assert f"riskfield view --connect {demo.endpoint} --robot demo1" in said.getvalue()


def test_view_writes_the_layout_of_another_robot(tmp_path):
    out = tmp_path / "layout.json"
    r = subprocess.run([sys.executable, "-m", "riskfield", "view", "--foxglove", "--write-layout", str(out),
                        "--robot", "limo9", "--prefix", "site1/rf"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert json.loads(out.read_text()) == layout("site1/rf/limo9") != layout("rf/limo1")


def test_without_the_sdk_the_error_names_the_extra():
    code = ("import sys\nsys.modules['foxglove'] = None\nfrom riskfield.cli import app\n"
            "app(['view', '--foxglove', '--duration', '1'], prog_name='riskfield')\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "COLUMNS": "200"})
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "install 'riskfield[foxglove]'" in r.stderr, r.stderr


# -- the node over Zenoh, read by a WebSocket client ---------------------------------------------

def esdf() -> EsdfGrid:
    d = (np.arange(6 * 4, dtype=np.float32).reshape(6, 4, 1) - 5) / 10
    return EsdfGrid(header=Header(stamp_ns=11), origin=(-0.5, -0.5, 0.0), voxel_size=0.1, distance=d,
                    risk_group=(d < 0).astype(np.uint8), groups=["high", "mid", "low"], max_distance=2.0,
                    unknown_is_occupied=False)


def frame() -> PerceptionFrame:
    h, w = 16, 16
    pts = np.zeros((h, w, 3), np.float32)
    pts[..., 2] = 2.0
    return PerceptionFrame(header=Header(stamp_ns=12), T_WC=np.eye(4), points=pts,
                           confidence=np.ones((h, w), np.float32), labels=np.full((h, w), 12, np.uint16),
                           keyframe_id=0)


def test_a_client_connected_before_any_message_is_offered_every_fixed_channel_at_once(router_endpoint: str):
    """The channels a key fixes exist before the server starts, so a client that connects first gets them in
    its first advertisement, none made while it is connected (the SDK's race: live.py, ``FoxgloveLive``)."""
    from riskfield.services.recorder.live import declared_views

    keys = Keys("t_foxglove_first")
    declared = {(v.topic, v.encoding, v.schema) for v in declared_views(keys)}
    assert {t for t, _, _ in declared} >= {keys.camera_image, keys.perception_frame, keys.state, f"{keys.root}/tf",
                                        f"{keys.root}/robot", keys.objects, keys.safety_status, keys.cmd_safe}
    args = ["--robot", keys.robot, "--set", "port=0", "--set", "status_period_s=0.1"]
    with ServiceProcess("foxglove", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("foxglove")), proc.output
        status = StatusWatch(s, keys.status("foxglove"))
        port = int(status.wait(lambda st: "foxglove_port" in st.extra, 30).extra["foxglove_port"])
        status.close()
        with websockets.sync.client.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"],
                                            open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=10))["op"] == "serverInfo"
            first = json.loads(ws.recv(timeout=10))
        assert proc.stop() == 0
    assert first["op"] == "advertise"
    # a JSON channel without a schema gets a generated schema name
    assert {(c["topic"], c["encoding"], c["schemaName"] if c["encoding"] == "protobuf" else "")
            for c in first["channels"]} == declared


def test_node_serves_every_channel_to_a_websocket_client(router_endpoint: str):
    keys = Keys("t_foxglove")
    jpeg = bytes.fromhex("ffd8ffe000104a46494600010100000100010000ffd9")  # served as it comes (no decoding)
    msgs = {
        keys.camera_image: Image(header=Header(stamp_ns=10), encoding="jpeg", width=2, height=2, data=jpeg),
        keys.esdf: esdf(),
        keys.perception_frame: frame(),
        keys.objects: people(13),
        keys.safety_status: SafetyStatus(header=Header(stamp_ns=14), h=0.1, risk_group=1, intervening=True,
                                         fallback="stale_map", solve_us=3.0, esdf_age_ms=900.0),
        keys.cmd_safe: VelocityCommand(header=Header(stamp_ns=15), linear=(0.25, 0, 0), angular=(0, 0, 0),
                                       source="filter"),
        keys.state: RobotState(header=Header(stamp_ns=16), position=(0.5, 0.25, 0), orientation=(0, 0, 0, 1),
                               linear_velocity=(0, 0, 0), angular_velocity=(0, 0, 0)),
    }
    wanted = {keys.camera_image, keys.esdf, keys.perception_frame, keys.objects, keys.safety_status, keys.cmd_safe,
              keys.state, f"{keys.root}/tf", f"{keys.root}/robot"}
    args = ["--robot", keys.robot, "--set", "port=0", "--set", "status_period_s=0.1"]
    stop = threading.Event()
    with ServiceProcess("foxglove", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("foxglove")), proc.output
        status = StatusWatch(s, keys.status("foxglove"))
        port = int(status.wait(lambda st: "foxglove_port" in st.extra, 30).extra["foxglove_port"])
        status.close()

        got: dict[str, list[tuple[str, bytes, int]]] = {}  # topic → (schema or encoding, payload, log time)

        def publish() -> None:  # until the client has seen every channel (the ESDF's is made on its first message)
            # A channel the client has seen is not put again (state and status go on: the footprint's
            # text needs both). Putting all seven, the point cloud among them, every 0.1 s can outrun a
            # node starved by a busy machine, whose bounded inbox then drops (CI missed one channel for 60 s).
            while not stop.is_set():
                for key, m in msgs.items():
                    if key not in got or key in (keys.state, keys.safety_status):
                        put(s, key, m)
                time.sleep(0.1)

        t = threading.Thread(target=publish, daemon=True)
        t.start()

        def robot_texts() -> set[str]:
            """What the footprint said: the first states may come before any status."""
            return {SceneUpdate.FromString(data).entities[0].texts[0].text
                    for _, data, _ in got.get(f"{keys.root}/robot", [])}
        try:
            with websockets.sync.client.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"],
                                    open_timeout=10) as ws:
                assert ws.subprotocol == "foxglove.sdk.v1"
                info = json.loads(ws.recv(timeout=10))
                assert info["op"] == "serverInfo" and info["name"] == f"riskfield {keys.robot}"
                channels: dict[int, dict] = {}
                deadline = time.monotonic() + 60
                while not (wanted <= got.keys() and "braking: stale_map" in robot_texts()):
                    assert time.monotonic() < deadline, f"missing {sorted(wanted - got.keys())}"
                    frame_ = ws.recv(timeout=30)
                    if isinstance(frame_, str):
                        m = json.loads(frame_)
                        if m["op"] == "advertise":
                            new = [c for c in m["channels"] if c["id"] not in channels]
                            channels.update({c["id"]: c for c in new})
                            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                                {"id": c["id"], "channelId": c["id"]} for c in new]}))
                        continue
                    op, sub, log_time = struct.unpack_from("<BIQ", frame_)
                    assert op == 0x01
                    c = channels[sub]
                    got.setdefault(c["topic"], []).append((c["schemaName"] or c["encoding"], frame_[13:], log_time))
        finally:
            stop.set()
            t.join()
        assert proc.stop() == 0

    def proto(topic: str, i: int = -1):
        schema, data, _ = got[topic][i]
        return PROTO[schema].FromString(data)

    assert proto(keys.camera_image).format == "jpeg" and proto(keys.camera_image).data == jpeg
    g = proto(keys.esdf)
    cells = np.frombuffer(g.data, dtype=np.dtype([("d", "<f4"), ("g", "u1")]))
    np.testing.assert_array_equal(cells["d"].reshape(4, 6).T, esdf().distance[:, :, 0])  # x fastest
    assert g.column_count == 6 and g.cell_size.x == pytest.approx(0.1)
    assert got[keys.esdf][-1][2] == 11  # logged at the map's stamp
    assert len(proto(keys.perception_frame).data) == 18 * 2 * 2  # every 8th pixel both ways, 18 B a point
    person = proto(keys.objects).entities[0]
    assert person.id == "object/3" and len(person.arrows) == 1
    robot = proto(f"{keys.root}/robot").entities[0]
    assert robot.cubes[0].pose.position.x == 0.5 and robot.cubes[0].size.x == pytest.approx(0.322)  # the LIMO
    # the footprint says the newest status's reason (the first state may come before any status)
    assert robot_texts() <= {"no safety status", "braking: stale_map"}
    assert proto(f"{keys.root}/tf").child_frame_id == "base_link"
    st_json = json.loads(got[keys.safety_status][-1][1])
    assert st_json["intervening"] is True and st_json["fallback"] == "stale_map"
    assert json.loads(got[keys.cmd_safe][-1][1])["linear"] == [0.25, 0.0, 0.0]
