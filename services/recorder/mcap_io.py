"""MCAP files of riskfield traffic: writing (raw and viewable channels) and crash-tolerant reading.

Layout (readable by any MCAP tool, e.g. Foxglove or ``mcap cat``):

- **viewable channels** (topic = the Zenoh key, e.g. ``rf/limo1/map/esdf``; the robot's
  transform on ``{root}/tf``): Foxglove's well-known protobuf schemas or schemaless JSON, see
  :mod:`.views`;
- **raw channels** (topic ``raw/{key}``, channel metadata ``riskfield_key`` = the key): one
  schema per message type, named like the ``"schema"`` value (``EsdfGrid/1``), schema encoding
  ``jsonschema`` with the message's JSON Schema (the one ``riskfield schema`` exports), message
  encoding ``msgpack``: each record's data is the Zenoh payload exactly as it was on the wire,
  so a replay is byte-identical. Recordings made before the viewable layout have raw channels
  with the key itself as topic; they read the same;
- ``log_time`` is the receive time, ``publish_time`` the header's ``stamp_ns``, ``sequence``
  the header's ``seq``.

Chunks carry CRCs of their uncompressed content. Reading streams the file record by record
(``mcap.stream_reader.StreamReader`` with ``validate_crcs=True``), so a file cut short by a
crash yields every complete chunk before it reports the cut.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import msgpack
from mcap.exceptions import EndOfFile, InvalidMagic
from mcap.records import Channel, Footer
from mcap.records import Message as McapMessage
from mcap.records import Schema as McapSchema
from mcap.stream_reader import CRCValidationError, StreamReader
from mcap.writer import CompressionType, Writer

from riskfield.protocol import REGISTRY, DecodeError, decode, encode

MESSAGE_ENCODING = "msgpack"
UNKNOWN_SCHEMA = "unknown"
RAW_PREFIX = "raw/"
KEY_META = "riskfield_key"
SCHEMA_META = "riskfield_schema"
MAGIC = b"\x89MCAP0\r\n"


def run_names() -> Iterator[tuple[str, str]]:
    """(file stem, summary file name) of a folder's recording runs in the order they are taken:
    ``recording`` / ``summary.json``, then ``recording-1`` / ``summary-1.json``, ..."""
    yield "recording", "summary.json"
    n = 1
    while True:
        yield f"recording-{n}", f"summary-{n}.json"
        n += 1


_RUN = re.compile(r"^recording(?:-([1-9][0-9]*))?\.mcap$")


def latest_recording(folder: str | Path) -> Path:
    """The first file of the newest run ``riskfield record`` left in ``folder`` (the highest
    ``recording-N.mcap``, else ``recording.mcap``, which is also what is returned when there is none)."""
    folder = Path(folder)
    # Split files are <stem>-001.mcap, ...: the leading zero keeps them apart up to the 99th.
    runs = [(int(m.group(1) or 0), p) for p in folder.glob("recording*.mcap") if (m := _RUN.match(p.name))]
    return max(runs)[1] if runs else folder / "recording.mcap"


def peek_schema(payload: bytes) -> tuple[str, int, int] | None:
    """(schema, stamp_ns, seq) of a payload without validating it; None if it is no message map."""
    obj = peek_map(payload)
    if obj is None:
        return None
    header = obj.get("header") if isinstance(obj.get("header"), dict) else {}
    stamp, seq = header.get("stamp_ns", 0), header.get("seq", 0)
    return obj["schema"], stamp if isinstance(stamp, int) and stamp >= 0 else 0, seq if isinstance(seq, int) else 0


def peek_map(payload: bytes) -> dict | None:
    """The unpacked message map of a payload, or None if it is not one."""
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception:
        return None
    if not isinstance(obj, dict) or not isinstance(obj.get("schema"), str):
        return None
    return obj


class McapRecorder:
    """Appends raw payloads and views to an MCAP stream, registering schemas and channels as they appear."""

    def __init__(self, stream: BinaryIO, *, compression: CompressionType = CompressionType.ZSTD):
        self._stream = stream
        self._writer = Writer(stream, compression=compression)
        self._writer.start(profile="", library="riskfield")
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[tuple[str, str, str], int] = {}
        self.count = 0
        self.skipped = 0

    def _schema_id(self, name: str, encoding: str, data: Callable[[], bytes]) -> int:
        sid = self._schemas.get((name, encoding))
        if sid is None:
            sid = self._schemas[(name, encoding)] = self._writer.register_schema(name, encoding, data())
        return sid

    def _channel(self, topic: str, encoding: str, schema_id: int, schema: str, metadata: dict[str, str]) -> int:
        ch = self._channels.get((topic, encoding, schema))
        if ch is None:
            ch = self._channels[(topic, encoding, schema)] = self._writer.register_channel(
                topic, encoding, schema_id, metadata=metadata)
        return ch

    def add(self, key: str, payload: bytes, log_time_ns: int) -> bool:
        """Record one raw payload; payloads that are not message maps are skipped (and counted)."""
        meta = peek_schema(payload)
        if meta is None:
            self.skipped += 1
            return False
        schema, stamp, seq = meta

        def json_schema() -> bytes:
            cls = REGISTRY.get(schema)
            return json.dumps(cls.model_json_schema() if cls else {}).encode()

        sid = self._schema_id(schema, "jsonschema", json_schema)
        ch = self._channel(RAW_PREFIX + key, MESSAGE_ENCODING, sid, schema, {KEY_META: key, SCHEMA_META: schema})
        self._writer.add_message(ch, log_time=log_time_ns, data=payload, publish_time=stamp or log_time_ns,
                                 sequence=seq & 0xFFFFFFFF)
        self.count += 1
        return True

    def add_view(self, topic: str, encoding: str, schema: str, schema_data: Callable[[], bytes], data: bytes,
                 log_time_ns: int, publish_time_ns: int, metadata: dict[str, str] | None = None) -> None:
        """Record one viewable message (protobuf with ``schema`` = its full name, or schemaless json)."""
        sid = self._schema_id(schema, encoding, schema_data) if schema else 0
        ch = self._channel(topic, encoding, sid, schema, metadata or {})
        self._writer.add_message(ch, log_time=log_time_ns, data=data, publish_time=publish_time_ns or log_time_ns)
        self.count += 1

    def flush(self) -> None:
        """End the chunk in progress and hand it to the OS: a crash after this loses nothing before it.

        ``mcap.writer.Writer.flush`` (mcap ≥ 1.6) finalises the open chunk with its CRC and message
        indexes and flushes the stream; no fsync, since a killed process leaves the OS's page cache
        intact (a power cut is not covered)."""
        self._writer.flush()

    @property
    def size(self) -> int:
        """Bytes written to the stream so far (the open chunk not included)."""
        return self._stream.tell()

    def finish(self) -> None:
        self._writer.finish()


@dataclass(frozen=True)
class Record:
    key: str
    schema: str
    payload: bytes
    log_time_ns: int
    raw: bool = True  # False: rebuilt from a JSON view (a message without arrays), not the wire bytes


class RecordingError(ValueError):
    """A recording that cannot be read (``exit_code`` 2) or is cut short or corrupt (1)."""

    def __init__(self, message: str, exit_code: int = 1):
        super().__init__(message)
        self.exit_code = exit_code


def check_recording(path: str | Path) -> None:
    """Refuse, with one sentence, a path that is no MCAP file at all (missing, empty, garbage)."""
    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"recording {p} does not exist", 2)
    with open(p, "rb") as f:
        head = f.read(len(MAGIC))
    if not head:
        raise RecordingError(f"recording {p} is empty", 2)
    if head != MAGIC:
        raise RecordingError(f"{p} is not an MCAP file (no MCAP magic at its start)", 2)


def _describe(exc: BaseException, offset: int) -> str:
    if isinstance(exc, CRCValidationError):
        return f"CRC mismatch in a chunk after byte {offset} (the file is corrupt): {exc}"
    what = str(exc) or exc.__class__.__name__
    return f"unreadable data after byte {offset} ({what}); the file is corrupt"


def iter_mcap(path: str | Path) -> Iterator[tuple[McapSchema | None, Channel, McapMessage]]:
    """(schema, channel, message) of every readable message in file order; raises
    :class:`RecordingError` once, after the last readable one, if the file is cut short or corrupt."""
    check_recording(path)
    schemas: dict[int, McapSchema] = {}
    channels: dict[int, Channel] = {}
    complete = False
    size = Path(path).stat().st_size
    with open(path, "rb") as f:
        reader = StreamReader(f, validate_crcs=True)
        records = reader.records
        while True:
            pos = f.tell()
            try:
                rec = next(records)
            except StopIteration:
                break
            except InvalidMagic as exc:
                raise RecordingError(f"{path} is not an MCAP file ({exc})", 2) from None
            except EndOfFile:
                break  # a record cut in the middle: reported below as a missing footer
            except Exception as exc:  # every decoding failure of a damaged file, whatever library raised it
                if not isinstance(exc, CRCValidationError) and f.tell() >= size:
                    break  # a record cut in the middle by the end of the file: reported below
                raise RecordingError(f"{path}: {_describe(exc, pos)}") from None
            if isinstance(rec, McapSchema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, McapMessage):
                ch = channels.get(rec.channel_id)
                if ch is not None:
                    yield schemas.get(ch.schema_id), ch, rec
            elif isinstance(rec, Footer):
                complete = True
    if not complete:
        raise RecordingError(f"{path} ends without an MCAP footer: the recording was cut short (a crash or kill);"
                             " every complete chunk before the cut was read")


def raw_key(channel: Channel) -> str | None:
    """The Zenoh key of a raw (msgpack) channel, None for a viewable channel."""
    if channel.message_encoding != MESSAGE_ENCODING:
        return None
    return channel.metadata.get(KEY_META, channel.topic)


def read_records(path: str | Path, *, raw_only: bool = False,
                 on_error: Callable[[RecordingError], None] | None = None) -> Iterator[Record]:
    """Every record of a riskfield MCAP file, in file (= receive) order.

    Raw channels give the wire bytes. Unless ``raw_only``, a key recorded only as a JSON view
    (commands and statuses in a default recording) is rebuilt into a wire payload when its
    message has no arrays, and a key recorded only as a Foxglove view comes with the view's
    protobuf bytes and schema name (``foxglove.PointCloud``); both are marked ``raw=False``.
    A cut or corrupt file raises :class:`RecordingError` after its last readable record, or
    calls ``on_error`` and stops.
    """
    raw_keys: set[str] = set()
    try:
        for schema, channel, message in iter_mcap(path):
            key = raw_key(channel)
            if key is not None:
                raw_keys.add(key)
                yield Record(key, schema.name if schema else UNKNOWN_SCHEMA, message.data, message.log_time)
                continue
            if raw_only or channel.topic in raw_keys:
                continue
            if channel.message_encoding != "json":
                # a Foxglove view of a key kept only as a view (camera, pointmaps): counted by readers
                # such as the demo report, never decodable as a riskfield message
                yield Record(channel.topic, schema.name if schema else UNKNOWN_SCHEMA, message.data,
                             message.log_time, raw=False)
                continue
            rebuilt = _rebuild(message.data)
            if rebuilt is not None:
                yield Record(channel.topic, rebuilt[0], rebuilt[1], message.log_time, raw=False)
    except RecordingError as exc:
        if on_error is None:
            raise
        on_error(exc)


def _rebuild(data: bytes) -> tuple[str, bytes] | None:
    try:
        obj = json.loads(data)
        msg = decode(msgpack.packb(obj, use_bin_type=True))
    except (ValueError, DecodeError, TypeError):
        return None
    return msg.SCHEMA, encode(msg)


@dataclass
class KeyInfo:
    raw: int = 0  # raw (replayable) messages
    views: int = 0  # viewable messages on this topic
    schema: str = ""


def scan(path: str | Path) -> tuple[dict[str, KeyInfo], RecordingError | None]:
    """Per key: raw and viewable message counts; and the error that ended reading, if any."""
    keys: dict[str, KeyInfo] = {}
    err: RecordingError | None = None
    try:
        for schema, channel, _ in iter_mcap(path):
            key = raw_key(channel)
            info = keys.setdefault(key or channel.topic, KeyInfo())
            if key is not None:
                info.raw += 1
                info.schema = schema.name if schema else UNKNOWN_SCHEMA
            else:
                info.views += 1
    except RecordingError as exc:
        if exc.exit_code == 2:
            raise
        err = exc
    return keys, err
