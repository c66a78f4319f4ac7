"""The ndarray field type of the wire contract.

On the wire an array is the msgpack map ``{"dtype": "<f4", "shape": [..], "data": <bin>}``:
numpy ``dtype.str``, C order. Receivers check the dtype *exactly* (a client that sends
``<f8`` where ``<f4`` is specified is wrong, not converted), the shape against the field's
pattern, the byte count before touching the data (a giant declared shape is rejected without
allocating), and finiteness for floating-point fields. Decoding is zero-copy over the
msgpack ``bin`` (``np.frombuffer``), so decoded arrays are read-only views.

Python code constructing a message may pass any ndarray (or nested list) that converts to
the field's dtype without changing kind; it is converted once, on construction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import GetCoreSchemaHandler, GetJsonSchemaHandler
from pydantic_core import PydanticCustomError, core_schema

#: Default cap on one array's bytes (decode side); override per call with ``Limits``.
DEFAULT_MAX_ARRAY_BYTES = 64 * 1024 * 1024


def _limit(info: core_schema.ValidationInfo | None) -> int:
    ctx = info.context if info is not None else None
    if isinstance(ctx, dict):
        return int(ctx.get("max_array_bytes", DEFAULT_MAX_ARRAY_BYTES))
    return DEFAULT_MAX_ARRAY_BYTES


def _fail(problem: str) -> PydanticCustomError:
    return PydanticCustomError("ndarray", "{problem}", {"problem": problem})


@dataclass(frozen=True)
class ArraySpec:
    """Dtype and shape pattern of one ndarray field; ``None`` in ``shape`` means any length."""

    dtype: str
    shape: tuple[int | None, ...]
    finite: bool = True

    @property
    def np_dtype(self) -> np.dtype:
        return np.dtype(self.dtype)

    # -- validation ---------------------------------------------------------------------
    def check(self, value: Any, info: core_schema.ValidationInfo | None = None) -> np.ndarray:
        if isinstance(value, dict):
            arr = self._from_wire(value, _limit(info))
        elif isinstance(value, np.ndarray):
            arr = self._convert(value)
        elif isinstance(value, (list, tuple)):
            try:
                arr = self._convert(np.asarray(value))
            except ValueError as exc:  # ragged nested lists
                raise _fail(f"not an array: {exc}") from None
        else:
            raise _fail(f"expected an ndarray map {{dtype, shape, data}}, got {type(value).__name__}")
        self._check_shape(arr.shape)
        if self.finite and arr.dtype.kind in "fc" and not np.isfinite(arr).all():
            raise _fail("NaN or Inf in a field that must be finite")
        return arr

    def _convert(self, arr: np.ndarray) -> np.ndarray:
        target = self.np_dtype
        if arr.dtype == target:
            return arr
        same_kind = arr.dtype.kind == target.kind or (
            arr.dtype.kind in "iub" and target.kind in "iu"
        ) or (arr.dtype.kind in "iu" and target.kind == "f")
        if not same_kind:
            raise _fail(f"dtype {arr.dtype.str!r} cannot become {self.dtype!r}")
        if target.kind in "iu" and arr.size:
            info = np.iinfo(target)
            if arr.min() < info.min or arr.max() > info.max:
                raise _fail(f"values outside the range of {self.dtype!r}")
        return np.ascontiguousarray(arr, dtype=target)

    def _from_wire(self, m: dict, max_bytes: int) -> np.ndarray:
        missing = {"dtype", "shape", "data"} - m.keys()
        if missing:
            raise _fail(f"ndarray map lacks {sorted(missing)}")
        dtype, shape, data = m["dtype"], m["shape"], m["data"]
        if dtype != self.dtype:
            raise _fail(f"dtype {dtype!r} where {self.dtype!r} is required")
        if not isinstance(shape, (list, tuple)) or not all(
            isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape
        ):
            raise _fail(f"shape must be a list of non-negative integers, got {shape!r}")
        self._check_shape(tuple(shape))
        nbytes = math.prod(shape) * self.np_dtype.itemsize
        if nbytes > max_bytes:
            raise _fail(f"array of {nbytes} bytes is over the limit of {max_bytes}")
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise _fail(f"data must be msgpack bin, got {type(data).__name__}")
        if len(data) != nbytes:
            raise _fail(f"data has {len(data)} bytes, shape {list(shape)} of {dtype} needs {nbytes}")
        return np.frombuffer(data, dtype=self.np_dtype).reshape(shape)

    def _check_shape(self, shape: tuple[int, ...]) -> None:
        if len(shape) != len(self.shape) or any(
            want is not None and got != want for got, want in zip(shape, self.shape, strict=False)
        ):
            pattern = "x".join("N" if s is None else str(s) for s in self.shape)
            raise _fail(f"shape {list(shape)} does not match {pattern}")

    # -- pydantic hooks -----------------------------------------------------------------
    def __get_pydantic_core_schema__(self, source: Any, handler: GetCoreSchemaHandler) -> Any:
        return core_schema.with_info_plain_validator_function(self.check)

    def __get_pydantic_json_schema__(self, schema: Any, handler: GetJsonSchemaHandler) -> dict:
        return self.json_schema()

    def json_schema(self) -> dict:
        ndim = len(self.shape)
        dims = "x".join("N" if s is None else str(s) for s in self.shape)
        return {
            "type": "object",
            "description": (
                f"ndarray {dims} of numpy dtype {self.dtype}, C order, raw bytes in 'data' (msgpack bin)"
                + ("; every value finite" if self.finite and self.np_dtype.kind == "f" else "")
            ),
            "required": ["dtype", "shape", "data"],
            "properties": {
                "dtype": {"const": self.dtype},
                "shape": {
                    "type": "array",
                    "minItems": ndim,
                    "maxItems": ndim,
                    "prefixItems": [
                        {"type": "integer", "minimum": 0}
                        if s is None
                        else {"type": "integer", "const": s}
                        for s in self.shape
                    ],
                },
                "data": {"type": "string", "contentEncoding": "binary"},
            },
            "x-ndarray": {"dtype": self.dtype, "shape": list(self.shape)},
        }


def to_wire(arr: np.ndarray) -> dict:
    """The msgpack map of an array; the data is a view, not a copy, when already C-contiguous."""
    arr = np.ascontiguousarray(arr)
    data = memoryview(arr).cast("B") if arr.size else b""
    return {"dtype": arr.dtype.str, "shape": list(arr.shape), "data": data}
