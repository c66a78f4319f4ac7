"""``riskfield view --foxglove``: the live stack over the Foxglove WebSocket protocol.

A thin node: it subscribes to a robot's keys, turns each message into the same views a recording
holds (``views``: Foxglove's protobuf schemas, JSON for the rest) and logs them on channels of the
official Foxglove SDK (``foxglove-sdk``), whose WebSocket server (``foxglove.start_server``; the
Foxglove WebSocket protocol under the SDK's subprotocol ``foxglove.sdk.v1``,
rust/foxglove/src/websocket/handshake.rs) Foxglove connects to: *Open connection → Foxglove WebSocket →
ws://HOST:8765*. The layout in ``deploy/foxglove/riskfield-layout.json`` (:func:`layout`) arranges
the topics below.

Topics (the robot's keys, ``{root}`` = ``{prefix}/{robot}``):

- ``{root}/camera/image``: ``foxglove.CompressedImage``;
- ``{root}/map/esdf``: ``foxglove.Grid`` (the slice; ``map/esdf3d``: ``foxglove.VoxelGrid``), cell
  fields ``distance`` (signed metres) and ``risk_group``;
- ``{root}/perception/frame``: ``foxglove.PointCloud`` in the map frame;
- ``{root}/state``: ``foxglove.PoseInFrame`` and ``{root}/tf`` (``map → base_link``);
- ``{root}/robot``: ``foxglove.SceneUpdate``, the footprint coloured by what the filter does and
  the reason it brakes;
- ``{root}/map/objects``: ``foxglove.SceneUpdate``, the tracked people and animals with velocity
  arrows;
- ``{root}/safety/status`` (``intervening``, ``fallback``: the filter's intervention and its
  reason, ``h``, ...), ``cmd/ref``, ``cmd/safe``, ``nav/goal``: JSON.

SDK API used (foxglove-sdk 0.30, ``python/foxglove-sdk/python/foxglove/__init__.py``
``start_server`` and ``channel.py`` ``Channel``; https://docs.foxglove.dev/docs/sdk/python): a
``Channel`` with a ``Schema(name, encoding="protobuf", data=FileDescriptorSet)`` and
``message_encoding="protobuf"`` takes the serialized bytes of a view; a schemaless JSON channel
takes the JSON bytes. Each node has its own ``foxglove.Context``, so two live views in one process
do not share channels.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, ClassVar

from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from pydantic import Field, field_validator

from riskfield.protocol import (
    EsdfGrid,
    Image,
    Keys,
    NavGoal,
    PerceptionFrame,
    RobotState,
    SafetyStatus,
    TrackedObjects,
    VelocityCommand,
    to_map,
)
from riskfield.protocol.platforms import PlanarPlatform, platform

from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .views import (
    ImageView,
    View,
    esdf_view,
    json_view,
    objects_view,
    pointcloud_view,
    proto_view,
    robot_view,
    state_views,
)

LAYOUT = Path(__file__).resolve().parents[2] / "deploy" / "foxglove" / "riskfield-layout.json"


class FoxgloveSettings(NodeSettings):
    SERVICE: ClassVar[str] = "foxglove"

    host: str = "127.0.0.1"
    """Address the Foxglove WebSocket server binds to (0.0.0.0 to be reached from other machines; the server
    has no authentication, so only on a trusted network)."""
    port: int = Field(8765, ge=0, le=65535)
    """TCP port of the Foxglove WebSocket server (0: any free port, shown in the node's status as foxglove_port)."""
    platform: str = "limo"
    """The robot's description (protocol/platforms.py PLATFORMS): a wheeled platform's body rectangle is the
    footprint drawn on {root}/robot, as the filter protects it."""
    robot_radius: float = Field(0.15, gt=0)
    """Radius of the disc drawn on {root}/robot for a platform described as a point (point_mass, multicopter) (m)."""

    @field_validator("platform")
    @classmethod
    def _known_platform(cls, name: str) -> str:
        platform(name)  # an unknown name is a ValueError listing the known ones
        return name

    @property
    def body(self) -> float | tuple[float, float]:
        """What ``robot_view`` draws: the body rectangle (length, width) or the disc's radius."""
        p = platform(self.platform)
        return (p.length, p.width) if isinstance(p, PlanarPlatform) else self.robot_radius
    cloud_stride: int = Field(8, ge=1)
    """Pointmap decimation of the point cloud: every n-th pixel both ways."""
    jpeg_quality: int = Field(75, ge=1, le=95)
    """JPEG quality of the camera view when the camera sends raw RGB (Pillow's scale)."""


class FoxgloveLive:
    """Logs views on SDK channels, one per (topic, schema): those of ``declared_views`` made at start, the
    others on their first message."""

    def __init__(self, node: Node, s: FoxgloveSettings):
        import foxglove

        self.fg, self.node, self.s = foxglove, node, s
        self.root = node.keys.root
        self.context = foxglove.Context()
        self.channels: dict[tuple[str, str], Any] = {}
        # Made before the server starts. The SDK (source read at 0.26) advertises the channels that exist
        # when a client connects before that client's tasks run (rust/foxglove/src/websocket/server.rs,
        # ``handle_connection``: ``register_client_and_advertise``, then ``client.run``). A channel made
        # while a client is connected is queued to it before it is recorded as advertised
        # (connected_client.rs, ``advertise_channels``), and ``on_subscribe`` refuses a subscription to a
        # channel not yet recorded ("Unknown channel ID"): on a busy machine the client's subscription can
        # come in between, and that client never gets the channel's messages.
        for v in declared_views(node.keys):
            self._channel(v)
        self.server = foxglove.start_server(name=f"riskfield {node.settings.robot}", host=s.host, port=s.port,
                                            context=self.context)
        self.port = int(self.server.port)
        node.stats["foxglove_port"] = float(self.port)
        node.log.info(f"Foxglove: open a Foxglove WebSocket connection to ws://{s.host}:{self.port} "
                      f"(layout: {LAYOUT.relative_to(LAYOUT.parents[2])})")
        self.image = ImageView(s.jpeg_quality)
        self.status: SafetyStatus | None = None
        self.logged = 0

    def _channel(self, v: View) -> Any:
        key = (v.topic, v.schema)
        ch = self.channels.get(key)
        if ch is None:
            meta = dict(v.metadata)
            if v.encoding == "protobuf":
                schema = self.fg.Schema(name=v.schema, encoding="protobuf", data=v.schema_data())
                ch = self.fg.Channel(v.topic, schema=schema, message_encoding="protobuf", context=self.context,
                                     metadata=meta)
            else:
                ch = self.fg.Channel(v.topic, message_encoding="json", context=self.context, metadata=meta)
            self.channels[key] = ch
        return ch

    def log(self, views: list[View], stamp_ns: int) -> None:
        for v in views:
            self._channel(v).log(v.data, log_time=stamp_ns)
            self.logged += 1
        self.node.stats["foxglove_logged"] = float(self.logged)

    # -- one handler per key --------------------------------------------------------------------
    def on_image(self, m: Image) -> None:
        self.log(self.image(self.node.keys.camera_image, m), m.header.stamp_ns)

    def on_esdf(self, key: str, m: EsdfGrid) -> None:
        self.log(esdf_view(key, m), m.header.stamp_ns)

    def on_frame(self, m: PerceptionFrame) -> None:
        self.log(pointcloud_view(self.node.keys.perception_frame, m, self.s.cloud_stride), m.header.stamp_ns)

    def on_state(self, m: RobotState) -> None:
        views = state_views(self.node.keys.state, f"{self.root}/tf", m)
        views += robot_view(f"{self.root}/robot", m, self.s.body, self.status)
        self.log(views, m.header.stamp_ns)

    def on_objects(self, m: TrackedObjects) -> None:
        self.log(objects_view(self.node.keys.objects, m), m.header.stamp_ns)

    def on_status(self, m: SafetyStatus) -> None:
        self.status = m
        self.log(json_view(self.node.keys.safety_status, to_map(m), m.SCHEMA), m.header.stamp_ns)

    def on_json(self, key: str, m: Any) -> None:
        self.log(json_view(key, to_map(m), m.SCHEMA), m.header.stamp_ns)

    def close(self) -> None:
        self.server.stop()


def declared_views(keys: Keys) -> list[View]:
    """An empty view of every channel whose schema and metadata its key fixes, made before the server
    starts (``FoxgloveLive.__init__``). Not the ESDF's: its channel carries the first grid's groups and
    range, and a 3-D grid is a VoxelGrid; nor the raw image of a machine without Pillow."""
    root = keys.root
    protos = ((keys.camera_image, CompressedImage), (keys.perception_frame, PointCloud), (keys.state, PoseInFrame),
              (f"{root}/tf", FrameTransform), (f"{root}/robot", SceneUpdate), (keys.objects, SceneUpdate))
    jsons = ((keys.safety_status, SafetyStatus), (keys.cmd_ref, VelocityCommand), (keys.cmd_safe, VelocityCommand),
             (keys.nav_goal, NavGoal))
    return [*(proto_view(topic, cls()) for topic, cls in protos),
            *(v for topic, m in jsons for v in json_view(topic, {}, m.SCHEMA))]


def setup(node: Node, s: FoxgloveSettings) -> FoxgloveLive:
    live = FoxgloveLive(node, s)
    k = node.keys
    node.subscribe(k.camera_image, Image, live.on_image)
    node.subscribe(k.esdf, EsdfGrid, lambda m: live.on_esdf(k.esdf, m))
    node.subscribe(k.esdf3d, EsdfGrid, lambda m: live.on_esdf(k.esdf3d, m))
    node.subscribe(k.perception_frame, PerceptionFrame, live.on_frame)
    node.subscribe(k.state, RobotState, live.on_state)
    node.subscribe(k.objects, TrackedObjects, live.on_objects)
    node.subscribe(k.safety_status, SafetyStatus, live.on_status, queue="fifo")
    node.subscribe(k.cmd_ref_any, VelocityCommand, lambda m: live.on_json(k.cmd_ref, m))
    node.subscribe(k.cmd_safe, VelocityCommand, lambda m: live.on_json(k.cmd_safe, m))
    node.subscribe(k.nav_goal, NavGoal, lambda m: live.on_json(k.nav_goal, m))
    return live


def layout(root: str = "rf/limo1") -> dict:
    """The Foxglove layout of the live view (and of recordings, which use the same topics): a 3-D
    panel with the ESDF grid, point cloud, robot and tracked objects; the camera; the filter's
    status and a plot of h and the commanded speeds. Built with the SDK's ``foxglove.layouts``."""
    import foxglove.layouts as fl

    topics = {
        f"{root}/map/esdf": fl.BaseRendererGridTopicSettings(visible=True, color_field="distance",
                                                             color_mode="colormap", color_map="turbo"),
        f"{root}/perception/frame": fl.BaseRendererPointCloudTopicSettings(visible=True, color_field="class_id",
                                                                           color_mode="colormap",
                                                                           point_size=3.0),
        f"{root}/robot": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
        f"{root}/map/objects": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
        f"{root}/state": fl.BaseRendererPoseTopicSettings(visible=False),
    }
    scene = fl.ThreeDeePanel(title="map, robot and people", config=fl.ThreeDeeConfig(
        follow_tf="base_link", topics=topics))
    camera = fl.ImagePanel(title="camera", config=fl.ImageConfig(
        image_mode=fl.ImageModeConfig(image_topic=f"{root}/camera/image")))
    status = fl.RawMessagesPanel(title="safety filter: intervention and reason", config=fl.RawMessagesConfig(
        topic_path=f"{root}/safety/status"))
    # A topic that does not start with "/" is quoted in a message path.
    plot = fl.PlotPanel(title="barrier h and speed", config=fl.PlotConfig(paths=[
        fl.PlotSeries(value=f'"{root}/safety/status".h', label="h (m)"),
        fl.PlotSeries(value=f'"{root}/cmd/ref".linear[0]', label="v ref (m/s)"),
        fl.PlotSeries(value=f'"{root}/cmd/safe".linear[0]', label="v safe (m/s)"),
    ]))
    right = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=2, content=camera), fl.SplitItem(proportion=1, content=status),
        fl.SplitItem(proportion=1, content=plot)])
    content = fl.SplitContainer(direction="row", items=[fl.SplitItem(proportion=2, content=scene),
                                                        fl.SplitItem(proportion=1, content=right)])
    return json.loads(fl.Layout(content=content).to_json())


SERVICE = ServiceSpec("foxglove", FoxgloveSettings, setup)
