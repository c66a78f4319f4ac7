"""A recording is never overwritten, and what waits to be written is bounded by bytes, over a real
Zenoh router: a second ``record`` into the same folder takes the next free name
(``recording-1.mcap``, ``summary-1.json``), and a byte-bounded queue drops its oldest samples,
counted, whatever their number."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from riskfield.protocol import NodeStatus, RobotState, encode
from riskfield.services.recorder.mcap_io import latest_recording
from riskfield.services.recorder.node import RecordSettings
from riskfield.services.runtime import Node, NodeSettings
from riskfield.services.runtime.inbox import ITEM_OVERHEAD
from riskfield.services.runtime.settings import UnknownSetting
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_matched, wait_until


def _state(x: float) -> bytes:
    return encode(RobotState(position=(x, 0.0, 0.0), orientation=(0, 0, 0, 1), linear_velocity=(0, 0, 0),
                             angular_velocity=(0, 0, 0)))


def _record_once(endpoint: str, robot: str, out: Path, x: float) -> None:
    args = ["--robot", robot, "--set", f"out={out}", "--set", "status_period_s=0.1"]
    with client_session(endpoint) as session:
        status = Collector(session, f"rf/{robot}/status/record", NodeStatus)
        with ServiceProcess("record", endpoint, args) as rec:
            assert wait_alive(session, f"rf/{robot}/alive/record"), rec.output
            status.wait(1, timeout_s=20)
            put(session, f"rf/{robot}/state", _state(x))
            assert wait_until(lambda: status.items[-1].extra.get("handled_data_messages", 0) >= 1, 20), rec.output
            assert rec.stop() == 0, rec.output
        status.close()


def test_a_second_recording_in_the_same_folder_takes_a_new_name(router_endpoint: str, tmp_path: Path) -> None:
    robot = "t_rec_twice"
    _record_once(router_endpoint, robot, tmp_path, 1.0)
    first = (tmp_path / "recording.mcap").read_bytes()
    first_summary = (tmp_path / "summary.json").read_text()
    _record_once(router_endpoint, robot, tmp_path, 2.0)
    assert (tmp_path / "recording.mcap").read_bytes() == first  # the first run is untouched
    assert (tmp_path / "summary.json").read_text() == first_summary
    second = json.loads((tmp_path / "summary-1.json").read_text())
    assert second["files"] == [str(tmp_path / "recording-1.mcap")] and second["per_key"][f"rf/{robot}/state"] == 1
    assert latest_recording(tmp_path) == tmp_path / "recording-1.mcap"
    _record_once(router_endpoint, robot, tmp_path, 3.0)
    assert latest_recording(tmp_path) == tmp_path / "recording-2.mcap"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "recording-1.mcap", "recording-2.mcap", "recording.mcap", "summary-1.json", "summary-2.json", "summary.json"]


def test_latest_recording_skips_split_files(tmp_path: Path) -> None:
    assert latest_recording(tmp_path) == tmp_path / "recording.mcap"  # none yet: the first run's name
    for name in ("recording.mcap", "recording-001.mcap", "recording-002.mcap", "recording-1.mcap",
                 "recording-1-001.mcap", "recording-3.mcap"):
        (tmp_path / name).write_bytes(b"")
    assert latest_recording(tmp_path) == tmp_path / "recording-3.mcap"


def test_the_queue_is_a_setting_in_megabytes() -> None:
    assert RecordSettings().max_queue_mb == 256.0
    with pytest.raises(UnknownSetting, match="max_queue_mb"):
        RecordSettings(max_queue=10)  # type: ignore[call-arg]  # the count bound it replaced
    with pytest.raises(ValueError, match="max_queue_mb"):
        RecordSettings(max_queue_mb=0)


def test_a_byte_bounded_subscription_drops_the_oldest_and_counts_them(router_endpoint: str) -> None:
    """The node's loop is held inside a handler while 12 samples of 100 kB arrive: a queue of 3
    samples' bytes keeps the newest 3 and counts 9 drops, however many more it could have held
    by count."""
    key = "rf/t_bytes/blob"
    size = 100_000
    node = Node("t-bytes", NodeSettings(connect=[router_endpoint], robot="t_bytes"))
    held, got = threading.Event(), []
    entered = threading.Event()

    def handler(_key: str, payload: bytes) -> None:
        entered.set()
        held.wait(20)
        got.append(payload[0])

    node.subscribe(key, None, handler, queue="fifo", maxlen=10**9, max_bytes=3 * (size + ITEM_OVERHEAD))
    loop = threading.Thread(target=node.run, daemon=True)
    loop.start()
    try:
        with client_session(router_endpoint) as s:
            assert wait_matched(s, key)
            put(s, key, bytes([0]) * size)
            assert entered.wait(10)  # the loop is inside the handler: the rest queue up
            for i in range(1, 13):
                put(s, key, bytes([i]) * size)
            assert wait_until(lambda: node.status().received["blob"] == 13, 10)
            held.set()
            assert wait_until(lambda: len(got) == 4, 10)
        st = node.status()
        assert got == [0, 10, 11, 12] and st.dropped["blob"] == 9
    finally:
        held.set()
        node.stop()
        loop.join(10)
