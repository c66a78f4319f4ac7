"""MCAP files of riskfield traffic.

Layout (readable by any MCAP tool, e.g. Foxglove or ``mcap cat``):

- one **channel per Zenoh key** (the channel topic is the full key, e.g. ``rf/limo1/map/esdf``);
- one **schema per message type**, named like the ``"schema"`` value (``EsdfGrid/1``), with
  schema encoding ``jsonschema`` and the message's JSON Schema as data (the one
  ``riskfield schema`` exports);
- message encoding ``msgpack``: each record's data is the Zenoh payload exactly as it was on
  the wire (arrays as ``{dtype, shape, data}`` maps), so a replay is byte-identical;
- ``log_time`` is the receive time, ``publish_time`` the header's ``stamp_ns``, ``sequence``
  the header's ``seq``.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import msgpack
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from riskfield.protocol import REGISTRY

MESSAGE_ENCODING = "msgpack"
UNKNOWN_SCHEMA = "unknown"


def peek_schema(payload: bytes) -> tuple[str, int, int] | None:
    """(schema, stamp_ns, seq) of a payload without validating it; None if it is no message map."""
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception:
        return None
    if not isinstance(obj, dict) or not isinstance(obj.get("schema"), str):
        return None
    header = obj.get("header") if isinstance(obj.get("header"), dict) else {}
    stamp, seq = header.get("stamp_ns", 0), header.get("seq", 0)
    return obj["schema"], stamp if isinstance(stamp, int) and stamp >= 0 else 0, seq if isinstance(seq, int) else 0


class McapRecorder:
    """Appends payloads to an MCAP file, registering schemas and channels as they appear."""

    def __init__(self, stream: BinaryIO, *, compression: CompressionType = CompressionType.ZSTD):
        self._writer = Writer(stream, compression=compression)
        self._writer.start(profile="", library="riskfield")
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self.count = 0
        self.skipped = 0

    def _schema_id(self, schema: str) -> int:
        sid = self._schemas.get(schema)
        if sid is None:
            cls = REGISTRY.get(schema)
            data = json.dumps(cls.model_json_schema() if cls else {}).encode()
            sid = self._schemas[schema] = self._writer.register_schema(schema, "jsonschema", data)
        return sid

    def add(self, key: str, payload: bytes, log_time_ns: int) -> bool:
        """Record one payload; payloads that are not message maps are skipped (and counted)."""
        meta = peek_schema(payload)
        if meta is None:
            self.skipped += 1
            return False
        schema, stamp, seq = meta
        ch = self._channels.get((key, schema))
        if ch is None:
            ch = self._channels[(key, schema)] = self._writer.register_channel(
                key, MESSAGE_ENCODING, self._schema_id(schema), metadata={"riskfield_schema": schema})
        self._writer.add_message(ch, log_time=log_time_ns, data=payload, publish_time=stamp or log_time_ns,
                                 sequence=seq & 0xFFFFFFFF)
        self.count += 1
        return True

    def finish(self) -> None:
        self._writer.finish()


@dataclass(frozen=True)
class Record:
    key: str
    schema: str
    payload: bytes
    log_time_ns: int


def read_records(path: str | Path) -> Iterator[Record]:
    """Every record of a riskfield MCAP file, in log-time order."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.message_encoding != MESSAGE_ENCODING:
                continue
            yield Record(channel.topic, schema.name if schema else UNKNOWN_SCHEMA, message.data, message.log_time)
