"""The embedded Zenoh router: a Python session in router mode, so no zenohd is needed."""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

from pydantic import Field
from pydantic_settings import NoDecode

from .node import Node
from .service import ServiceSpec
from .settings import DEFAULT_ENDPOINT, NodeSettings


class RouterSettings(NodeSettings):
    SERVICE: ClassVar[str] = "router"

    mode: Literal["peer", "client", "router"] = "router"
    """The router routes; peer or client turn it into a plain session."""
    listen: Annotated[list[str], NoDecode] = Field(default_factory=lambda: [DEFAULT_ENDPOINT])
    """Endpoints the router listens on: the nodes and the other routers dial these."""
    # Other routers to mesh with (e.g. the robot's router dialling the server's).
    connect: Annotated[list[str], NoDecode] = Field(default_factory=list)
    """Other routers to mesh with (e.g. the robot's router dialling the server's)."""
    compression: bool = True
    """LZ4 on the links to other routers (Zenoh's transport compression): the robot ↔ server link then
    carries a map/esdf message in about a quarter of its bytes. Zenoh compresses a link only when both
    of its ends enable it, and nodes never do, so the links to this site's nodes stay as they are."""

    def zenoh_extra(self) -> dict[str, object]:
        # eclipse-zenoh/zenoh, io/zenoh-transport/src/unicast/establishment/ext/compression.rs
        # (``CompressionFsm``): each end ANDs its own flag with the other's InitSyn / InitAck extension.
        return {"transport/unicast/compression/enabled": self.compression}


def setup(node: Node, settings: RouterSettings) -> Any:
    node.log.info("router listening on %s", ", ".join(settings.listen))
    return None


SERVICE = ServiceSpec("router", RouterSettings, setup)
