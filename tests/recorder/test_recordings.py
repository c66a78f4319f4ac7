"""Viewable recordings (Foxglove schemas), replay that cannot drive a robot, crash-safe files.

Everything runs for real: the recorder and `riskfield replay` as processes over a loopback
router, the files read back with the `mcap` reader and decoded with protobuf's own decoder
(mcap-protobuf-support's DecoderFactory builds the classes from the schemas in the file).
"""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap_protobuf.decoder import DecoderFactory

from riskfield.protocol import (
    EsdfGrid,
    Image,
    LimoDiagnostics,
    NavGoal,
    NodeStatus,
    PerceptionFrame,
    RiskConfig,
    RobotState,
    SafetyStatus,
    VelocityCommand,
    decode,
    encode,
)
from riskfield.services.recorder.mcap_io import McapRecorder, RecordingError, read_records, scan
from riskfield.services.recorder.replay import COMMAND_KEYS, STATE_KEYS, Remap, plan
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_until

PY = sys.executable


@pytest.fixture(autouse=True)
def _delete_recordings(tmp_path):
    """Recordings can be large: nothing a test wrote outlives it."""
    yield
    shutil.rmtree(tmp_path, ignore_errors=True)


def _esdf(nz: int = 1, v: float = 1.25) -> EsdfGrid:
    d = np.full((6, 4, nz), v, np.float32)
    d[2, 1, 0] = -0.5
    g = np.zeros((6, 4, nz), np.uint8)
    g[2, 1, 0] = 2
    return EsdfGrid(origin=(1.0, -2.0, 0.1), voxel_size=0.1, distance=d, risk_group=g,
                    groups=["high", "mid", "low"], max_distance=2.0, unknown_is_occupied=False)


def _frame() -> PerceptionFrame:
    h, w = 16, 16
    pts = np.zeros((h, w, 3), np.float32)
    pts[..., 2] = 2.0  # 2 m in front of the camera
    T = np.eye(4)
    T[:3, 3] = (5.0, 0.0, 0.3)
    return PerceptionFrame(T_WC=T, points=pts, confidence=np.full((h, w), 0.75, np.float32),
                           labels=np.full((h, w), 12, np.uint16), keyframe_id=3)


def _image() -> Image:
    rng = np.random.default_rng(0)
    return Image(encoding="rgb8", width=32, height=24, data=rng.integers(0, 255, (24, 32, 3), dtype=np.uint8))


def _state() -> RobotState:
    return RobotState(position=(1.5, 2.5, 0.0), orientation=(0.0, 0.0, 0.0, 1.0),
                      linear_velocity=(0.1, 0, 0), angular_velocity=(0, 0, 0))


def _contract(robot: str) -> dict[str, bytes]:
    """One payload for every published key of the wire contract (map/esdf/query is a query)."""
    k = f"rf/{robot}/"
    msgs = {
        "camera/image": _image(), "perception/frame": _frame(), "map/esdf": _esdf(), "map/esdf3d": _esdf(nz=3),
        "state": _state(), "cmd/ref": VelocityCommand(linear=(0.3, 0, 0), angular=(0, 0, 0.1), source="joystick"),
        "cmd/safe": VelocityCommand(linear=(0.2, 0, 0), angular=(0, 0, 0.1), source="safety-filter"),
        "safety/status": SafetyStatus(h=0.4, risk_group=1, intervening=True, fallback=None, solve_us=80.0,
                                      esdf_age_ms=12.0),
        "nav/goal": NavGoal(waypoints=np.array([[1.0, 2.0, 0.0]]), tolerance=0.2, loop=False),
        "config/risk": RiskConfig(), "sim/truth": _frame(),
        "limo/diagnostics": LimoDiagnostics(port="/dev/null", connected=True, battery_v=12.1, error_bits=0,
                                            vehicle_state=0, control_mode=1, motion_mode=0,
                                            command_mode_confirmed=True, mode_mismatch=False, frames_ok=1,
                                            frames_bad=0, bytes_skipped=0, reconnects=0, watchdog_stops=0,
                                            commands=1),
    }
    return {k + rel: encode(m) for rel, m in msgs.items()}


def _record(router_endpoint: str, robot: str, out: Path, payloads: dict[str, bytes], *extra: str) -> dict:
    """Run the recorder, put every payload once, wait until it has recorded them, stop it."""
    args = ["--robot", robot, "--set", f"out={out}", "--set", "status_period_s=0.1", *extra]
    with client_session(router_endpoint) as session:
        status = Collector(session, f"rf/{robot}/status/record", NodeStatus)
        with ServiceProcess("record", router_endpoint, args) as rec:
            assert wait_alive(session, f"rf/{robot}/alive/record"), rec.output
            # the subscription is declared before the liveliness token; a status proves the loop runs
            status.wait(1, timeout_s=20)
            for key, payload in payloads.items():
                put(session, key, payload)
            assert wait_until(lambda: status.items[-1].extra.get("handled_data_messages", 0) >= len(payloads),
                              20), rec.output
            assert rec.stop() == 0, rec.output
        status.close()
    return json.loads((out / "summary.json").read_text())


def _channels(path: Path) -> dict[str, tuple[str, str]]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {c.topic: (c.message_encoding, summary.schemas[c.schema_id].name if c.schema_id else "")
            for c in summary.channels.values()}


def _decoded(path: Path) -> dict[str, object]:
    """Last message per viewable topic, decoded: protobuf by protobuf's own decoder from the
    schema in the file, JSON by json."""
    out: dict[str, object] = {}
    factory = DecoderFactory()
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding == "protobuf":
                out[channel.topic] = factory.decoder_for("protobuf", schema)(message.data)
            elif channel.message_encoding == "json":
                out[channel.topic] = json.loads(message.data)
    return out


# -- viewable by default ---------------------------------------------------------------------------


def test_default_recording_is_viewable_and_keeps_filter_inputs_raw(router_endpoint, tmp_path):
    robot = "t_view"
    payloads = _contract(robot)
    summary = _record(router_endpoint, robot, tmp_path, payloads)
    path = tmp_path / "recording.mcap"
    assert summary["per_key"][f"rf/{robot}/camera/image"] == 1
    ch = _channels(path)
    k = f"rf/{robot}/"
    assert ch[k + "camera/image"] == ("protobuf", "foxglove.CompressedImage")
    assert ch[k + "map/esdf"] == ("protobuf", "foxglove.Grid")
    assert ch[k + "map/esdf3d"] == ("protobuf", "foxglove.VoxelGrid")
    assert ch[k + "perception/frame"] == ("protobuf", "foxglove.PointCloud")
    assert ch[f"rf/{robot}/tf"] == ("protobuf", "foxglove.FrameTransform")
    assert ch[k + "state"] == ("protobuf", "foxglove.PoseInFrame")
    for rel in ("cmd/safe", "cmd/ref", "safety/status", "nav/goal"):
        assert ch[k + rel] == ("json", ""), rel
    raw = {t for t, (enc, _) in ch.items() if enc == "msgpack"}
    assert raw == {f"raw/{k}{rel}" for rel in ("map/esdf", "state", "cmd/ref", "nav/goal")}

    views = _decoded(path)
    img = views[k + "camera/image"]
    assert img.format == "jpeg"
    from PIL import Image as PILImage

    assert PILImage.open(io.BytesIO(img.data)).size == (32, 24)

    grid = views[k + "map/esdf"]
    assert [f.name for f in grid.fields] == ["distance", "risk_group"]
    cells = np.frombuffer(grid.data, np.dtype([("d", "<f4"), ("g", "u1")])).reshape(4, 6)  # rows = y
    assert cells["d"][1, 2] == pytest.approx(-0.5) and cells["g"][1, 2] == 2  # voxel i=2, j=1
    assert cells["d"][0, 0] == pytest.approx(1.25)
    assert grid.pose.position.x == pytest.approx(0.95) and grid.cell_size.x == pytest.approx(0.1)

    vox = views[k + "map/esdf3d"]
    assert (vox.row_count, vox.column_count, vox.slice_stride) == (4, 6, 5 * 24)

    cloud = views[k + "perception/frame"]
    pts = np.frombuffer(cloud.data, np.dtype([("p", "<f4", 3), ("c", "<f4"), ("l", "<u2")]))
    assert cloud.frame_id == "map" and len(pts) == 4  # 16×16 pixels, every 8th both ways
    np.testing.assert_allclose(pts["p"], [[5.0, 0.0, 2.3]] * 4, atol=1e-6)  # world frame: T_WC applied
    assert np.all(pts["c"] == 0.75) and np.all(pts["l"] == 12)

    tf = views[f"rf/{robot}/tf"]
    assert (tf.parent_frame_id, tf.child_frame_id) == ("map", "base_link")
    assert (tf.translation.x, tf.translation.y) == (1.5, 2.5)
    assert views[k + "safety/status"]["intervening"] is True
    assert views[k + "cmd/safe"]["linear"][0] == pytest.approx(0.2)

    # the report's reader still gets statuses and commands, rebuilt from their JSON views
    recs = {r.key: r for r in read_records(path)}
    assert decode(recs[k + "cmd/safe"].payload, VelocityCommand).source == "safety-filter"
    assert not recs[k + "cmd/safe"].raw and recs[k + "cmd/ref"].raw
    assert recs[k + "map/esdf"].payload == payloads[k + "map/esdf"]  # raw: the wire bytes


def test_include_exclude_patterns(router_endpoint, tmp_path):
    robot = "t_incl"
    payloads = _contract(robot)
    wanted = {k: v for k, v in payloads.items() if "/map/" in k and not k.endswith("esdf3d")}
    summary = _record(router_endpoint, robot, tmp_path, payloads, "--set", "include=map/**",
                      "--set", f"exclude=rf/{robot}/map/esdf3d")
    assert set(summary["per_key"]) == set(wanted) == {f"rf/{robot}/map/esdf"}
    assert summary["filtered_out"] >= len(payloads) - 1


# -- replay: every contract key with --raw, commands withheld by default -------------------------


def _replay(args: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-m", "riskfield", "replay", *args], capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


@pytest.fixture
def raw_recording(router_endpoint, tmp_path):
    robot = "t_raw"
    payloads = _contract(robot)
    _record(router_endpoint, robot, tmp_path, payloads, "--set", "raw=true")
    yield tmp_path / "recording.mcap", robot, payloads
    (tmp_path / "recording.mcap").unlink(missing_ok=True)


@pytest.mark.parametrize("include_commands", [True, False])
def test_replay_of_raw_recording_reproduces_contract_keys(router_endpoint, raw_recording, include_commands):
    """Command keys and the robot's state are withheld unless asked for (both flags here at once)."""
    path, robot, payloads = raw_recording
    new = f"t_rp{int(include_commands)}"
    held = (*COMMAND_KEYS, *STATE_KEYS)
    expected = {k.replace(f"rf/{robot}/", f"rf/{new}/"): v for k, v in payloads.items()
                if include_commands or not any(k == f"rf/{robot}/{c}" for c in held)}
    assert include_commands or f"rf/{robot}/state" in payloads
    with client_session(router_endpoint) as session:
        got = Collector(session, f"rf/{new}/**")
        args = [str(path), "-e", router_endpoint, "--remap-from", f"rf/{robot}/", "--remap-to", f"rf/{new}"]
        r = _replay(args + (["--include-commands", "--include-state"] if include_commands else []))
        assert r.returncode == 0, r.stderr
        # the replay has ended: everything it published was put before it exited
        assert wait_until(lambda: set(expected) <= set(got.keys), 10), (set(expected) - set(got.keys), r.stderr)
        received = {k: got.items[i] for i, k in enumerate(got.keys) if "/status/" not in k}
        got.close()
    assert received == expected  # byte-identical, and nothing else (no command or state key without the flags)
    if not include_commands:
        assert "withheld" in r.stderr and "cmd/safe" in r.stderr and f"rf/{robot}/state" in r.stderr


def test_default_recording_replay_says_what_it_cannot_reproduce(router_endpoint, tmp_path):
    robot = "t_cannot"
    _record(router_endpoint, robot, tmp_path, _contract(robot))
    r = _replay([str(tmp_path / "recording.mcap"), "--dry-run"])
    assert r.returncode == 0, r.stderr
    out = r.stderr
    assert f"publish   rf/{robot}/map/esdf" in out and f"withheld  rf/{robot}/state  (the robot's state" in out
    for rel in ("camera/image", "perception/frame", "cmd/safe", "safety/status"):
        assert f"cannot    rf/{robot}/{rel}" in out, rel
    assert f"withheld  rf/{robot}/cmd/ref" in out and f"withheld  rf/{robot}/nav/goal" in out


# -- remaps ------------------------------------------------------------------------------------------


def test_remap_validation():
    assert Remap("rf/limo1/", "rf/replay1/")("rf/limo1/cmd/safe") == "rf/replay1/cmd/safe"  # slash normalised
    assert Remap("rf/limo1", "rf/copy")("rf/limo10/x") == "rf/limo10/x"  # whole chunks only
    for bad in ("rf/*", "rf/**", "rf/$*", "rf//x", "", "/"):
        with pytest.raises(ValueError):
            Remap("rf/limo1", bad)
        with pytest.raises(ValueError):
            Remap(bad, "rf/limo1")
    with pytest.raises(ValueError, match="both"):
        Remap("rf/limo1", None)
    from riskfield.services.recorder.mcap_io import KeyInfo

    keys = {"rf/limo1/state": KeyInfo(raw=3), "rf/limo1/cmd/safe": KeyInfo(raw=2)}
    with pytest.raises(ValueError, match="matches no recorded key"):
        plan(keys, Remap("rf/limo2", "rf/x"))
    p = plan(keys, Remap("rf/limo1", "rf/x"))
    assert p.publish == {} and p.withheld == ["rf/limo1/cmd/safe"] and p.withheld_state == ["rf/limo1/state"]
    p = plan(keys, Remap("rf/limo1", "rf/x"), include_state=True)
    assert p.publish == {"rf/limo1/state": ("rf/x/state", 3)} and p.withheld == ["rf/limo1/cmd/safe"]


def test_replay_cli_refuses_bad_remaps(tmp_path):
    path = tmp_path / "r.mcap"
    with open(path, "wb") as f:
        rec = McapRecorder(f)
        rec.add("rf/limo1/state", encode(_state()), 1_000)
        rec.finish()
    for frm, to, what in (("rf/limo1", "rf/*", "wildcard"), ("rf/nobody", "rf/x", "matches no recorded key"),
                          ("rf/**", "rf/x", "wildcard")):
        r = _replay([str(path), "--remap-from", frm, "--remap-to", to, "--dry-run"], timeout=30)
        assert r.returncode == 2 and what in r.stderr and "Traceback" not in r.stderr, r.stderr
    r = _replay([str(path), "--remap-from", "rf/limo1/", "--remap-to", "rf/copy", "--include-state", "--dry-run"],
                timeout=30)
    assert r.returncode == 0 and "rf/limo1/state → rf/copy/state" in r.stderr, r.stderr


# -- crash safety and damaged files -------------------------------------------------------------------


@pytest.mark.slow
def test_recorder_killed_loses_at_most_about_a_second(router_endpoint, tmp_path):
    robot = "t_kill"
    args = ["--robot", robot, "--set", f"out={tmp_path}", "--set", "status_period_s=0.1"]
    path = tmp_path / "recording.mcap"
    with client_session(router_endpoint) as session:
        status = Collector(session, f"rf/{robot}/status/record", NodeStatus)
        with ServiceProcess("record", router_endpoint, args) as rec:
            assert wait_alive(session, f"rf/{robot}/alive/record"), rec.output
            status.wait(1, timeout_s=20)
            sent = [0]

            def publish_one() -> bool:
                sent[0] += 1
                put(session, f"rf/{robot}/cmd/ref", VelocityCommand(linear=(0.01 * sent[0], 0, 0),
                                                                   angular=(0, 0, 0), source="t"))
                last = status.items[-1]
                # enough messages, taken in over more than two flush periods
                return (last.extra.get("handled_data_messages", 0) >= 150
                        and last.uptime_s - status.items[0].uptime_s > 2.5)

            assert wait_until(publish_one, 30), rec.output
            early = status.items[-1].extra["handled_data_messages"]
            first_seen = status.items[-1].uptime_s
            # keep publishing through one more flush period, then kill it mid-stream
            assert wait_until(lambda: publish_one() and status.items[-1].uptime_s > first_seen + 1.2, 10)
            rec.proc.send_signal(signal.SIGKILL)
            rec.proc.wait(10)
        status.close()
    assert path.stat().st_size > 0
    errors: list[RecordingError] = []
    got = [r for r in read_records(path, on_error=errors.append) if r.key.endswith("/cmd/ref") and r.raw]
    assert errors and "cut short" in str(errors[0])  # no footer: the kill is noticed
    assert len(got) >= early  # everything recorded more than a flush before the kill is there
    assert decode(got[0].payload, VelocityCommand).linear[0] == pytest.approx(0.01)  # the earliest ones too
    r = _replay([str(path), "--dry-run"], timeout=30)
    assert r.returncode == 1 and "cut short" in r.stderr and "Traceback" not in r.stderr, r.stderr


def _write(path: Path, n: int = 50, **kw) -> list[int]:
    """A recording of ``n`` states in chunks of 10; the file size after each chunk."""
    sizes = []
    with open(path, "wb") as f:
        rec = McapRecorder(f, **kw)
        for i in range(n):
            rec.add("rf/limo1/state", encode(_state()), 1_000_000 * (i + 1))
            if i % 10 == 9:
                rec.flush()
                sizes.append(rec.size)
        rec.finish()
    return sizes


@pytest.mark.parametrize("case", ["empty", "garbage", "missing"])
def test_replay_of_no_recording_is_one_line_and_exit_2(tmp_path, case):
    path = tmp_path / "bad.mcap"
    if case == "empty":
        path.write_bytes(b"")
    elif case == "garbage":
        path.write_bytes(os.urandom(4096))
    r = subprocess.run(["timeout", "30", PY, "-m", "riskfield", "replay", str(path), "-e", "tcp/127.0.0.1:9"],
                       capture_output=True, text=True, stdin=subprocess.DEVNULL)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    with pytest.raises(RecordingError) as exc:
        list(read_records(path))
    assert exc.value.exit_code == 2


def test_replay_of_truncated_file_plays_what_is_readable(router_endpoint, tmp_path):
    full = tmp_path / "full.mcap"
    sizes = _write(full)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[: sizes[2] + 40])  # three whole chunks and the start of the fourth
    readable = list(read_records(cut, on_error=lambda e: None))
    assert len(readable) == 30
    with client_session(router_endpoint) as session:
        got = Collector(session, "rf/t_cut/state")
        r = subprocess.run(["timeout", "60", PY, "-m", "riskfield", "replay", str(cut), "-e", router_endpoint,
                            "--remap-from", "rf/limo1", "--remap-to", "rf/t_cut", "--speed", "100", "--include-state"],
                           capture_output=True, text=True, stdin=subprocess.DEVNULL)
        assert r.returncode == 1, r.stderr
        assert wait_until(lambda: len(got.items) == len(readable), 10), (len(got.items), r.stderr)
        got.close()
    errors = [ln for ln in r.stderr.splitlines() if "ERROR" in ln]
    assert len(errors) == 1 and "cut short" in errors[0] and "Traceback" not in r.stderr, r.stderr


def test_crc_mismatch_is_reported(tmp_path):
    path = tmp_path / "crc.mcap"
    sizes = _write(path, compression=CompressionType.NONE)
    data = bytearray(path.read_bytes())
    at = data.find(b"\xacRobotState/1", sizes[1])  # a message inside the third chunk
    assert sizes[1] < at < sizes[2]
    data[at + 20] ^= 0xFF
    path.write_bytes(bytes(data))
    _, err = scan(path)
    assert err is not None and "CRC mismatch" in str(err)
    r = subprocess.run(["timeout", "30", PY, "-m", "riskfield", "replay", str(path), "--dry-run"],
                       capture_output=True, text=True, stdin=subprocess.DEVNULL)
    assert r.returncode == 1 and "CRC mismatch" in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_flipped_bytes_in_a_compressed_chunk_never_hang_or_traceback(tmp_path):
    path = tmp_path / "z.mcap"
    _write(path)
    data = bytearray(path.read_bytes())
    for i in range(len(data) // 3, len(data) // 3 + 64):
        data[i] ^= 0x5A
    path.write_bytes(bytes(data))
    r = subprocess.run(["timeout", "30", PY, "-m", "riskfield", "replay", str(path), "--dry-run"],
                       capture_output=True, text=True, stdin=subprocess.DEVNULL)
    assert r.returncode in (1, 2) and "Traceback" not in r.stderr, r.stderr
    assert "corrupt" in r.stderr or "CRC" in r.stderr or "truncated" in r.stderr, r.stderr


@pytest.mark.parametrize("timed", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_size_limit_and_file_splitting(router_endpoint, tmp_path, timed):
    """The recorder splits past ``split_mb`` and stops past ``max_mb``. By how much a file or the
    total overshoots depends on what arrives within one flush period, i.e. on the machine's load:
    those bounds are checked only ``timed`` (slow)."""
    robot = f"t_split_{int(timed)}"
    rng = np.random.default_rng(1)
    big = encode(EsdfGrid(origin=(0, 0, 0), voxel_size=0.1, distance=rng.random((64, 64, 1), np.float32),
                          risk_group=np.zeros((64, 64, 1), np.uint8), groups=["high"], max_distance=2.0,
                          unknown_is_occupied=False))  # ≈ 20 kB raw and 20 kB as a Grid, incompressible
    args = ["--robot", robot, "--set", f"out={tmp_path}", "--set", "status_period_s=0.1", "--set", "flush_s=0.2",
            "--set", "split_mb=0.15", "--set", "max_mb=0.5"]
    with client_session(router_endpoint) as session:
        status = Collector(session, f"rf/{robot}/status/record", NodeStatus)
        with ServiceProcess("record", router_endpoint, args) as rec:
            assert wait_alive(session, f"rf/{robot}/alive/record"), rec.output
            status.wait(1, timeout_s=20)
            # publish until the recorder stops by itself at its size limit
            assert wait_until(lambda: put(session, f"rf/{robot}/map/esdf", big) or not rec.alive(), 60,
                              period_s=0.01), rec.output
            assert rec.proc.wait(10) == 0, rec.output
            assert "size limit" in rec.output
        status.close()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["stopped_for_size"]
    files = [Path(f) for f in summary["files"]]
    assert files[0].name == "recording.mcap" and files[1].name == "recording-001.mcap" and len(files) >= 3
    sizes = [f.stat().st_size for f in files]
    assert sum(sizes) >= 0.5e6 and all(s >= 0.15e6 for s in sizes[:-1])
    if timed:
        assert sum(sizes) < 0.5e6 + 0.3e6  # stops within about one flush period past the limit
        assert all(s < 0.15e6 + 0.3e6 for s in sizes)
    for f in files:  # every part is a complete MCAP file of its own
        keys, err = scan(f)
        assert err is None and keys[f"rf/{robot}/map/esdf"].raw > 0
    assert any(s.extra.get("record_mb_per_s", 0) > 0 for s in status.items)  # the live rate is published


# -- views, unit level -----------------------------------------------------------------------------


def test_views_without_pillow_fall_back_to_raw_image(monkeypatch):
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    from riskfield.services.recorder.views import ImageView

    monkeypatch.setitem(sys.modules, "PIL", None)  # as if pillow were not installed
    view = ImageView()
    (v,) = view("rf/a/camera/image", _image())
    assert view.pillow_missing and v.schema == "foxglove.RawImage"
    raw = RawImage.FromString(v.data)
    assert (raw.width, raw.height, raw.encoding, raw.step) == (32, 24, "rgb8", 96)
    assert raw.data == _image().data.tobytes()


def test_voxel_grid_layout_is_x_fastest_then_y_then_z():
    from foxglove_schemas_protobuf.VoxelGrid_pb2 import VoxelGrid

    from riskfield.services.recorder.views import esdf_view

    g = _esdf(nz=3)
    g.distance[4, 3, 2] = 0.125
    (v,) = esdf_view("rf/a/map/esdf3d", g)
    vox = VoxelGrid.FromString(v.data)
    cells = np.frombuffer(vox.data, np.dtype([("d", "<f4"), ("g", "u1")]))
    at = 2 * vox.slice_stride + 3 * vox.row_stride + 4 * vox.cell_stride  # z=2, y=3, x=4
    assert cells["d"][at // vox.cell_stride] == pytest.approx(0.125)
    assert vox.pose.position.z == pytest.approx(0.05) and vox.cell_size.z == pytest.approx(0.1)


def test_a_recorded_lock_or_unlock_is_withheld_like_the_commands():
    """A replayed unlock would release a live robot's lock on its cmd/ref arbitration."""
    from riskfield.services.recorder.replay import is_command

    assert is_command("rf/limo1/cmd/lock") and not is_command("rf/limo1/cmd/lockout")
    # each source's own key too (protocol.keys.REF_SOURCES): a replayed joystick would drive
    assert all(is_command(f"rf/limo1/{k}") for k in ("cmd/ref/joystick", "cmd/ref/ros2/nav", "cmd/lock/operator"))
    assert not is_command("rf/limo1/cmd/refx/joystick") and not is_command("rf/limo1/map/esdf")
