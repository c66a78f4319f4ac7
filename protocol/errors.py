"""The one error type a receiver sees for a payload it cannot accept."""

from __future__ import annotations


class DecodeError(ValueError):
    """A payload is not a valid message of the wire contract.

    ``field`` is the dotted path of the offending field (``None`` when the payload as a
    whole is at fault: not msgpack, no schema, unknown schema) and ``problem`` says what
    is wrong in words a log reader understands.
    """

    def __init__(self, problem: str, *, schema: str | None = None, field: str | None = None):
        self.problem = problem
        self.schema = schema
        self.field = field
        where = ".".join(p for p in (schema, field) if p)
        super().__init__(f"{where}: {problem}" if where else problem)


class EncodeError(ValueError):
    """A message cannot be put on the wire (it holds NaN/Inf or an array of the wrong kind)."""
