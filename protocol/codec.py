"""msgpack codec of the wire contract.

``encode(msg)`` → bytes; ``decode(payload)`` → a validated message or one ``DecodeError``
naming the field and the problem. Arrays travel as ``{"dtype", "shape", "data"}`` maps
and decode as zero-copy views over the payload's ``bin`` objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypeVar, overload

import msgpack
import numpy as np
from pydantic import BaseModel, ValidationError

from .arrays import DEFAULT_MAX_ARRAY_BYTES, to_wire
from .errors import DecodeError, EncodeError
from .messages import MESSAGE_TYPES, Message
from .risk import RiskConfig

M = TypeVar("M", bound=Message)

#: Every schema this codec knows, by its ``"schema"`` value.
REGISTRY: dict[str, type[Message]] = {t.SCHEMA: t for t in (*MESSAGE_TYPES, RiskConfig)}

ENCODING = "application/msgpack"


@dataclass(frozen=True)
class Limits:
    """What a receiver accepts at most: whole payload bytes and bytes of one array."""

    max_payload_bytes: int = 256 * 1024 * 1024
    max_array_bytes: int = DEFAULT_MAX_ARRAY_BYTES


DEFAULT_LIMITS = Limits()


# -- encode --------------------------------------------------------------------------------


def _wire(value: Any, path: str) -> Any:
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc" and not np.isfinite(value).all():
            raise EncodeError(f"{path}: NaN or Inf in an array")
        return to_wire(value)
    if isinstance(value, BaseModel):
        return {k: _wire(getattr(value, k), f"{path}.{k}") for k in type(value).model_fields}
    if isinstance(value, float):
        if not math.isfinite(value):
            raise EncodeError(f"{path}: {value} is not finite")
        return value
    if isinstance(value, (list, tuple)):
        return [_wire(v, f"{path}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, dict):
        return {k: _wire(v, f"{path}.{k}") for k, v in value.items()}
    if isinstance(value, np.generic):
        return _wire(value.item(), path)
    return value


def to_map(msg: Message) -> dict[str, Any]:
    """The msgpack map of a message (before packing). Raises ``EncodeError`` on NaN/Inf."""
    body = _wire(msg, type(msg).SCHEMA)
    return {"schema": type(msg).SCHEMA, **body}


def encode(msg: Message) -> bytes:
    """Pack a message; never emits NaN/Inf (``EncodeError`` instead)."""
    return msgpack.packb(to_map(msg), use_bin_type=True)


# -- decode --------------------------------------------------------------------------------


def _unpack(payload: bytes | bytearray | memoryview, limits: Limits) -> dict:
    n = len(payload)
    if n > limits.max_payload_bytes:
        raise DecodeError(f"payload of {n} bytes is over the limit of {limits.max_payload_bytes}")
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=False, max_bin_len=n, max_str_len=n)
    except Exception as exc:  # msgpack raises several unrelated types for malformed input
        raise DecodeError(f"not msgpack ({type(exc).__name__}: {exc})") from None
    if not isinstance(obj, dict):
        raise DecodeError(f"not a msgpack map but {type(obj).__name__}")
    return obj


def _field_path(loc: tuple) -> str:
    return ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in loc).replace(".[", "[")


@overload
def decode(payload: bytes | bytearray | memoryview, expected: type[M], limits: Limits = ...) -> M: ...
@overload
def decode(payload: bytes | bytearray | memoryview, expected: None = ..., limits: Limits = ...) -> Message: ...


def decode(
    payload: bytes | bytearray | memoryview,
    expected: type[Message] | None = None,
    limits: Limits = DEFAULT_LIMITS,
) -> Message:
    """Unpack and validate one message; with ``expected``, also require that schema."""
    obj = _unpack(payload, limits)
    schema = obj.get("schema")
    if not isinstance(schema, str):
        raise DecodeError("no 'schema' string in the message map")
    cls = REGISTRY.get(schema)
    if cls is None:
        raise DecodeError(f"unknown schema {schema!r}")
    if expected is not None and cls is not expected:
        raise DecodeError(f"schema {schema!r} where {expected.SCHEMA!r} is expected")
    try:
        return cls.model_validate(obj, context={"max_array_bytes": limits.max_array_bytes})
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        field = _field_path(tuple(err.get("loc", ()))) or None
        raise DecodeError(err.get("msg", "invalid"), schema=schema, field=field) from None
