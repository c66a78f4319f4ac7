"""``riskfield record`` and ``riskfield replay``: thin nodes around mcap_io and replay."""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from pathlib import Path
from typing import ClassVar

from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .mcap_io import McapRecorder, read_records
from .replay import Remap, schedule


class RecordSettings(NodeSettings):
    SERVICE: ClassVar[str] = "record"

    out: Path = Path("out/record")
    keys: str = ""  # key expression to record; default: everything of this robot
    max_queue: int = 10000


class Recording:
    """Owns the MCAP file of a record node; ``close()`` finishes it and writes summary.json."""

    def __init__(self, node: Node, s: RecordSettings):
        s.out.mkdir(parents=True, exist_ok=True)
        self.path = s.out / "recording.mcap"
        self._file = open(self.path, "wb")
        self._rec = McapRecorder(self._file)
        self._per_key: Counter[str] = Counter()
        self._out = s.out
        self._t0 = time.time()
        self._node = node
        self.expr = s.keys or f"{node.keys.root}/**"
        node.subscribe(self.expr, None, self._on_payload, queue="fifo", maxlen=s.max_queue)
        node.log.info("recording %s into %s", self.expr, self.path)

    def _on_payload(self, key: str, payload: bytes) -> None:
        # arrival time, not handling time: a burst handled at once keeps its real spacing
        if self._rec.add(key, payload, self._node.arrival_ns or time.time_ns()):
            self._per_key[key] += 1

    def close(self) -> None:
        self._rec.finish()
        self._file.close()
        summary = {"file": str(self.path), "key_expr": self.expr, "messages": self._rec.count,
                   "skipped_not_messages": self._rec.skipped, "duration_s": time.time() - self._t0,
                   "per_key": dict(sorted(self._per_key.items()))}
        (self._out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")


def setup_record(node: Node, s: RecordSettings) -> Recording:
    return Recording(node, s)


RECORD = ServiceSpec("record", RecordSettings, setup_record)


class ReplaySettings(NodeSettings):
    SERVICE: ClassVar[str] = "replay"

    file: Path = Path("out/record/recording.mcap")
    speed: float = 1.0
    loop: bool = False
    remap_from: str | None = None  # e.g. rf/limo1
    remap_to: str | None = None  # e.g. rf/replay1
    skip_status: bool = True  # node counters of the recorded run are not replayed


class Replayer:
    """Publishes a recording on a thread with its original timing; stops the node at the end."""

    def __init__(self, node: Node, s: ReplaySettings):
        if not s.file.is_file():
            raise FileNotFoundError(f"recording {s.file} does not exist")
        self.node, self.s = node, s
        self.remap = Remap(s.remap_from, s.remap_to)
        self.published = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="replay", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            start = time.monotonic()
            for due, rec in schedule(read_records(self.s.file), self.s.speed):
                if self.s.skip_status and "/status/" in rec.key:
                    continue
                delay = start + due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    return
                self.node.publish_raw(self.remap(rec.key), rec.payload)
                self.published += 1
            if not self.s.loop:
                break
        self.node.log.info("replay finished: %d messages", self.published)
        self.node.stop("replay finished")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def setup_replay(node: Node, s: ReplaySettings) -> Replayer:
    return Replayer(node, s)


REPLAY = ServiceSpec("replay", ReplaySettings, setup_replay)
