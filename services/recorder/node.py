"""``riskfield record`` and ``riskfield replay``: thin nodes around mcap_io, views and replay.

A recording never overwrites a file: a run takes the first free name in its folder,
``recording.mcap`` (and ``summary.json``), then ``recording-1.mcap`` (``summary-1.json``),
``recording-2.mcap``, ...; its split files are ``<name>-001.mcap``, ... (``latest_recording``
finds a folder's newest run). The recorder's queue is bounded by bytes (``max_queue_mb``): a
recorder that cannot keep up drops the oldest samples, counted in its status (``dropped``,
``queue_dropped``), instead of growing without bound.
"""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any, ClassVar

import zenoh
from pydantic import Field, field_validator

from riskfield.protocol import EsdfGrid, Image, PerceptionFrame, RobotState, decode
from riskfield.protocol.errors import DecodeError
from riskfield.protocol.keys import base_of

from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .mcap_io import (
    RAW_PREFIX,
    McapRecorder,
    RecordingError,
    check_recording,
    peek_map,
    read_records,
    run_names,
    scan,
)
from .replay import Remap, is_command, is_state, is_status, plan, schedule
from .views import ImageView, View, esdf_view, json_view, pointcloud_view, state_views

#: Keys (relative to the robot root) kept as raw msgpack by default: what drives the safety
#: filter, so a default recording can replay it. ``raw=true`` keeps every key raw.
FILTER_INPUTS = ("map/esdf", "state", "state/relocalise", "cmd/ref", "nav/goal")
MB = 1e6


class RecordSettings(NodeSettings):
    SERVICE: ClassVar[str] = "record"

    out: Path = Field(Path("out/record"), description=(
        "folder of the recording: recording.mcap and summary.json, or the first free recording-N.mcap and "
        "summary-N.json when an earlier run is there (never overwritten)"))
    keys: str = ""
    """Key expression to subscribe to; empty: every key of this robot."""
    raw: bool = False
    """Keep the wire bytes of every key (all replayable), not only the filter's inputs."""
    include: list[str] = Field(default_factory=list)
    """Record only keys matching these key expressions (full, or relative to the robot); empty: all."""
    exclude: list[str] = Field(default_factory=list)
    """Skip keys matching these key expressions, e.g. sim/**."""
    max_mb: float = Field(0.0, ge=0)
    """Stop recording when the files reach this size in total (MB); 0: no limit."""
    split_mb: float = Field(0.0, ge=0)
    """Start a new file (recording-001.mcap, ...) past this size (MB); 0: one file."""
    flush_s: float = Field(1.0, gt=0, le=10)
    """Period of flushing to disk: a crash loses at most this much."""
    cloud_stride: int = Field(8, ge=1)
    """Pointmap decimation of the point-cloud view: every n-th pixel both ways."""
    jpeg_quality: int = Field(75, ge=1, le=100)
    """JPEG quality of the recorded camera view (Pillow's scale)."""
    status_line: bool = True
    """A live line with MB and MB/s on a terminal (else a log line every 10 s)."""
    max_queue_mb: float = Field(256.0, gt=0, le=65536, description=(
        "bytes of samples (MB) waiting to be written at most; past it the oldest are dropped and counted "
        "(status: dropped, queue_dropped)"))

    @field_validator("include", "exclude", mode="before")
    @classmethod
    def _patterns(cls, v: Any) -> Any:
        if isinstance(v, str):
            v = [p for p in v.split(",") if p.strip()]
        return v


class KeyFilter:
    """Include/exclude by Zenoh key expressions (``*`` one chunk, ``**`` any chunks), given in full
    or relative to the robot root; matching is Zenoh's own ``KeyExpr.includes``."""

    def __init__(self, root: str, include: list[str], exclude: list[str]):
        self.include = [self._expr(root, p) for p in include]
        self.exclude = [self._expr(root, p) for p in exclude]

    @staticmethod
    def _expr(root: str, pattern: str) -> list[zenoh.KeyExpr]:
        p = pattern.strip().strip("/")
        try:
            out = [zenoh.KeyExpr(p)]
            out.append(zenoh.KeyExpr(f"{root}/{p}"))
        except Exception as exc:  # zenoh raises ZError for a malformed expression
            raise ValueError(f"bad key pattern {pattern!r}: {exc}") from None
        return out

    def __call__(self, key: str) -> bool:
        k = zenoh.KeyExpr(key)
        if self.include and not any(e.includes(k) for pair in self.include for e in pair):
            return False
        return not any(e.includes(k) for pair in self.exclude for e in pair)


class Recording:
    """Owns the MCAP files of a record node; ``close()`` finishes them and writes summary.json."""

    def __init__(self, node: Node, s: RecordSettings):
        s.out.mkdir(parents=True, exist_ok=True)
        self.s, self._node, self._out = s, node, s.out
        self.keys, self.root = node.keys, node.keys.root
        self.filter = KeyFilter(self.root, s.include, s.exclude)
        self.files: list[Path] = []
        self._closed_bytes = 0
        self._open_first_file()
        self._per_key: Counter[str] = Counter()
        self._bytes: Counter[str] = Counter()
        self._filtered = 0
        self._handled_data = 0  # messages taken in on keys other than node statuses, recorded or filtered out
        self._bad = 0
        self._image = ImageView(s.jpeg_quality)
        self._warned_pillow = False
        self._t0 = time.time()
        self._last = (time.monotonic(), 0)
        self._last_log = time.monotonic()
        self._tty = s.status_line and sys.stderr.isatty()
        self.stopped_for_size = False
        self.expr = s.keys or f"{self.root}/**"
        # Bounded by bytes, not count: 10 000 pointmaps of 3.5 MB would be 35 GB (inbox.py).
        node.subscribe(self.expr, None, self._on_payload, queue="fifo", maxlen=10**9,
                       max_bytes=round(s.max_queue_mb * MB))
        node.every(s.flush_s, self._tick)
        node.on_close(self._end_line)
        node.log.info("recording %s into %s (%s)", self.expr, self.path,
                      "raw: every key" if s.raw else "viewable; raw: " + ", ".join(FILTER_INPUTS))

    # -- files ----------------------------------------------------------------------------------
    def _open_first_file(self) -> None:
        """The first free run name of the folder (module doc); exclusive creation, so a file that
        appeared meanwhile (another recorder on the same folder) is never overwritten either."""
        for stem, summary in run_names():
            if (self._out / summary).exists():
                continue
            try:
                self._file = open(self._out / f"{stem}.mcap", "xb")
            except FileExistsError:
                continue
            self.stem, self.summary_path, self.path = stem, self._out / summary, self._out / f"{stem}.mcap"
            break
        self.files.append(self.path)
        self._rec = McapRecorder(self._file)
        if self.stem != "recording":
            self._node.log.info("%s already holds a recording: this one is %s", self._out, self.path.name)

    def _open_file(self) -> None:
        n = len(self.files)
        while True:
            path = self._out / f"{self.stem}-{n:03d}.mcap"
            try:
                self._file = open(path, "xb")
                break
            except FileExistsError:
                n += 1
        self.path = path
        self.files.append(self.path)
        self._rec = McapRecorder(self._file)

    def _close_file(self) -> None:
        self._rec.finish()
        self._closed_bytes += self._file.tell()
        self._file.close()

    @property
    def total_bytes(self) -> int:
        return self._closed_bytes + self._rec.size

    # -- recording ------------------------------------------------------------------------------
    def _raw_wanted(self, key: str) -> bool:
        relative = self.keys.relative(key)
        return self.s.raw or (relative is not None and base_of(relative) in FILTER_INPUTS)

    def _on_payload(self, key: str, payload: bytes) -> None:
        if not is_status(key):  # tests and tools wait on this count
            self._handled_data += 1
            self._node.stats["handled_data_messages"] = self._handled_data
        if self.stopped_for_size:
            return
        if not self.filter(key):
            self._filtered += 1
            return
        # arrival time, not handling time: a burst handled at once keeps its real spacing
        t = self._node.arrival_ns or time.time_ns()
        wrote = False
        if self._raw_wanted(key):
            wrote = self._rec.add(key, payload, t)
            self._bytes[RAW_PREFIX + key] += len(payload)
        obj = peek_map(payload)
        if obj is None:
            if not wrote:
                self._rec.skipped += 1
            return
        for v in self._views(key, payload, obj):
            self._rec.add_view(v.topic, v.encoding, v.schema, v.schema_data, v.data, t,
                               _stamp(obj) or t, dict(v.metadata))
            self._bytes[v.topic] += len(v.data)
            wrote = True
        if wrote:
            self._per_key[key] += 1

    def _views(self, key: str, payload: bytes, obj: dict) -> list[View]:
        schema = obj["schema"]
        try:
            if schema == Image.SCHEMA:
                views = self._image(key, decode(payload, Image))
                if self._image.pillow_missing and not self._warned_pillow:
                    self._warned_pillow = True
                    self._node.log.warning("pillow is not installed (pip install 'riskfield[sim]'): camera images "
                                           "are recorded as foxglove.RawImage, uncompressed")
                return views
            if schema == EsdfGrid.SCHEMA:
                return esdf_view(key, decode(payload, EsdfGrid))
            if schema == PerceptionFrame.SCHEMA:
                return pointcloud_view(key, decode(payload, PerceptionFrame), self.s.cloud_stride)
            if schema == RobotState.SCHEMA:
                return state_views(key, f"{self.root}/tf", decode(payload, RobotState))
        except DecodeError as exc:
            self._bad += 1
            self._node.ratelog(logging.WARNING, f"invalid:{key}", f"not viewable, invalid message on {key}: {exc}")
            return []
        if schema.startswith(("DistanceQuery/", "DistanceReply/")):
            return []
        return json_view(key, obj, schema)

    def _tick(self) -> None:
        """Every ``flush_s``: end the open chunk (crash safety), rotate or stop on size, report."""
        self._rec.flush()
        s = self.s
        if s.max_mb and self.total_bytes >= s.max_mb * MB and not self.stopped_for_size:
            self.stopped_for_size = True
            self._node.log.warning("size limit of %g MB reached: recording stopped", s.max_mb)
            self._node.stop(f"size limit of {s.max_mb:g} MB reached")
        elif s.split_mb and self._rec.size >= s.split_mb * MB:
            self._close_file()
            self._open_file()
            self._node.log.info("continuing in %s", self.path)
        self._status()

    def _status(self) -> None:
        now, size = time.monotonic(), self.total_bytes
        t_prev, size_prev = self._last
        rate = (size - size_prev) / MB / max(now - t_prev, 1e-3)
        self._last = (now, size)
        self._node.stats.update(recorded_mb=size / MB, record_mb_per_s=rate, queue_dropped=self._queue_dropped())
        line = (f"recording {self.path.name}: {size / MB:8.1f} MB  {rate:6.2f} MB/s  "
                f"{sum(self._per_key.values())} messages  {time.time() - self._t0:5.0f} s")
        if self._tty:
            sys.stderr.write("\r" + line + "\x1b[K")
            sys.stderr.flush()
        elif self.s.status_line and now - self._last_log >= 10.0:
            self._last_log = now
            self._node.log.info(line)

    def _end_line(self) -> None:
        if self._tty:  # the node's last log lines start on a line of their own
            self._tty = False
            sys.stderr.write("\n")

    def close(self) -> None:
        self._close_file()
        self._end_line()
        dur = time.time() - self._t0
        total = self._closed_bytes
        summary = {"files": [str(p) for p in self.files], "file": str(self.files[0]), "key_expr": self.expr,
                   "raw": "every key" if self.s.raw else list(FILTER_INPUTS),
                   "messages": self._rec.count, "skipped_not_messages": self._rec.skipped,
                   "filtered_out": self._filtered, "invalid": self._bad, "duration_s": dur,
                   "size_mb": total / MB, "mb_per_s": total / MB / max(dur, 1e-3),
                   "stopped_for_size": self.stopped_for_size, "queue_dropped": self._queue_dropped(),
                   "per_key": dict(sorted(self._per_key.items())),
                   "payload_mb_per_key": {k: round(v / MB, 3) for k, v in sorted(self._bytes.items())}}
        self.summary_path.write_text(json.dumps(summary, indent=2) + "\n")

    def _queue_dropped(self) -> int:
        return sum(self._node.status().dropped.values())


def _stamp(obj: dict) -> int:
    h = obj.get("header")
    st = h.get("stamp_ns", 0) if isinstance(h, dict) else 0
    return st if isinstance(st, int) and st >= 0 else 0


def setup_record(node: Node, s: RecordSettings) -> Recording:
    return Recording(node, s)


RECORD = ServiceSpec("record", RecordSettings, setup_record)


class ReplaySettings(NodeSettings):
    SERVICE: ClassVar[str] = "replay"

    file: Path = Path("out/record/recording.mcap")
    """The recording to replay (made by riskfield record)."""
    speed: float = Field(1.0, gt=0)
    """Time scale: 2 replays twice as fast."""
    loop: bool = False
    """Start again at the end."""
    remap_from: str | None = None
    """Key prefix to rewrite, e.g. rf/limo1 (with remap_to)."""
    remap_to: str | None = None
    """New key prefix, e.g. rf/replay1."""
    include_commands: bool = False
    """Also publish cmd/safe, cmd/ref and nav/goal (withheld by default: they can drive a live robot)."""
    include_state: bool = Field(False, description=(
        "also publish the recorded state and state/relocalise: withheld by default, a recorded state beside a "
        "live robot moves its map and feeds its filter a position it is not at"))
    skip_status: bool = True
    """Leave out the recorded run's node status (its counters are not this run's)."""
    verify: bool = True
    """Scan the file and check the remap before publishing (the CLI has done it already)."""


#: The outcome of the last replay in this process: the runtime's ``run()`` returns 0 for every
#: clean stop, so the command line reads a cut or corrupt recording's exit code from here.
LAST_REPLAY: dict[str, Any] = {}


class Replayer:
    """Publishes a recording's raw channels on a thread with its original timing; stops the node at the end."""

    def __init__(self, node: Node, s: ReplaySettings):
        self.node, self.s = node, s
        self.remap = Remap(s.remap_from, s.remap_to)
        if s.verify:
            check_recording(s.file)
            keys, _ = scan(s.file)
            plan(keys, self.remap, include_commands=s.include_commands, skip_status=s.skip_status,
                 include_state=s.include_state)
        self.published = 0
        self.withheld: Counter[str] = Counter()
        self.error: RecordingError | None = None
        self.exit_code = 0
        LAST_REPLAY.clear()
        LAST_REPLAY["replayer"] = self
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="replay", daemon=True)
        self._thread.start()

    def _keep(self, key: str) -> bool:
        if self.s.skip_status and is_status(key):
            return False
        if is_command(key) and not self.s.include_commands:
            self.withheld[key] += 1
            return False
        if is_state(key) and not self.s.include_state:
            self.withheld[key] += 1
            return False
        return True

    def _run(self) -> None:
        try:
            self._play()
        except RecordingError as exc:
            self.error, self.exit_code = exc, exc.exit_code
            self.node.log.error("%s", exc)
        except Exception as exc:  # never a silent hang: anything else ends the replay with one line
            self.error, self.exit_code = RecordingError(f"replay failed: {exc!r}"), 1
            self.node.log.error("replay failed: %r", exc)
        if self.withheld:
            self.node.log.info("withheld command and state keys (use --include-commands, --include-state): %s",
                               ", ".join(sorted(self.withheld)))
        self.node.log.info("replay finished: %d messages", self.published)
        self.node.stop("replay finished" if not self.exit_code else "replay stopped at a damaged part of the file")

    def _play(self) -> None:
        while not self._stop.is_set():
            start = time.monotonic()
            for due, rec in schedule(read_records(self.s.file, raw_only=True), self.s.speed):
                if not self._keep(rec.key):
                    continue
                delay = start + due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    return
                self.node.publish_raw(self.remap(rec.key), rec.payload)
                self.published += 1
            if not self.s.loop:
                break

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def setup_replay(node: Node, s: ReplaySettings) -> Replayer:
    return Replayer(node, s)


REPLAY = ServiceSpec("replay", ReplaySettings, setup_replay)
