"""A diagnostic node: subscribe to ``in_key``, validate as ``schema``, republish on ``out_key``.

Useful to bridge a message between robots or prefixes, and the smallest complete example
of a riskfield node. Keys without a leading '/' are relative to ``{prefix}/{robot}/``.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from riskfield.protocol import REGISTRY, Message

from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings


class RelaySettings(NodeSettings):
    SERVICE: ClassVar[str] = "relay"

    in_key: str = "relay/in"
    """Key read, relative to {prefix}/{robot}/ (a leading / makes it absolute)."""
    out_key: str = "relay/out"
    """Key each decoded message is published on again, relative like in_key."""
    schema_name: str = "VelocityCommand/1"
    """Wire schema of in_key, e.g. VelocityCommand/1: a message that does not decode is dropped and counted."""
    queue: Literal["latest", "fifo"] = "fifo"
    """fifo forwards every message; latest only the newest when the relay falls behind."""


def _absolute(node: Node, key: str) -> str:
    return key[1:] if key.startswith("/") else node.keys.key(key)


def setup(node: Node, s: RelaySettings) -> None:
    if s.schema_name not in REGISTRY:
        raise ValueError(f"unknown schema {s.schema_name!r}; known: {', '.join(REGISTRY)}")
    out = _absolute(node, s.out_key)

    def forward(msg: Message) -> None:
        node.publish(out, msg)

    node.subscribe(_absolute(node, s.in_key), REGISTRY[s.schema_name], forward, queue=s.queue)


SERVICE = ServiceSpec("relay", RelaySettings, setup)
