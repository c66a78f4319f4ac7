"""Viewable forms of riskfield messages: Foxglove's well-known schemas (protobuf) and JSON.

Pure functions, no I/O: each takes one message (already decoded) and returns the views to
write, as :class:`View` records. The recorder writes them beside (or instead of) the raw
msgpack payloads; any MCAP viewer that knows the ``foxglove.*`` schemas draws them.

Schemas and their encoding come from ``foxglove-schemas-protobuf`` (the compiled ``.proto``
files of https://docs.foxglove.dev/docs/visualization/message-schemas/introduction) and are
registered with ``mcap_protobuf.schema.build_file_descriptor_set`` (mcap-protobuf-support,
https://mcap.dev/guides/python/protobuf): schema name = the message's full protobuf name
(``foxglove.Grid``), schema encoding ``protobuf``, data = a serialized ``FileDescriptorSet``.
Not ``foxglove-sdk`` here: it gives the same protobuf bytes at the same encode cost, but it is a
54 MB native wheel whose writer owns the file, while these two packages are about 3 MB with
protobuf and write through the ``mcap`` Writer the raw channels use (one file, one chunking and
CRC policy), and ``mcap_protobuf.decoder.DecoderFactory`` reads the views back.
Messages without a Foxglove counterpart become schemaless JSON (message encoding ``json``,
schema id 0, as https://docs.foxglove.dev/docs/sdk/schemas describes).

- ``camera/image`` → ``foxglove.CompressedImage`` (JPEG; an ``rgb8`` image is compressed with
  pillow). Without pillow an ``rgb8`` image is written as ``foxglove.RawImage`` (viewable,
  about 10× larger) and the recorder says so once.
- ``EsdfGrid`` with one z layer (``map/esdf``) → ``foxglove.Grid``; with several
  (``map/esdf3d``) → ``foxglove.VoxelGrid``. Cell fields: ``distance`` (float32, metres, the
  real signed distance) and ``risk_group`` (uint8, 1-based index into the channel metadata's
  ``groups``), so a viewer can colour by either.
- ``PerceptionFrame`` (``perception/frame``, ``sim/truth``) → ``foxglove.PointCloud`` in the
  ``map`` frame: every ``stride``-th pixel in both directions, :math:`p_W = R_{WC} p_C + t_{WC}`,
  fields ``x y z`` (float32), ``confidence`` (float32) and ``class_id`` (uint16, ADE20K).
- ``RobotState`` (``state``) → ``foxglove.FrameTransform`` ``map → base_link`` on
  ``{root}/tf`` and ``foxglove.PoseInFrame`` on the key itself.
- ``TrackedObjects`` (``map/objects``) → ``foxglove.SceneUpdate``: per object a cylinder of its
  radius, coloured by risk group, an arrow of its velocity (its length the distance covered in one
  second) and a label; the update first deletes every entity, so an object no longer tracked
  disappears.
- ``RobotState`` with the newest ``SafetyStatus`` → ``foxglove.SceneUpdate`` of the robot's
  footprint (``robot_view``, the live view's ``{root}/robot``): green while the filter passes the
  command, amber while it intervenes, red while it brakes, with the reason as text.
- anything else → JSON of the message map (small arrays as nested lists).
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Grid_pb2 import Grid
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.SceneEntityDeletion_pb2 import SceneEntityDeletion
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.VoxelGrid_pb2 import VoxelGrid
from mcap_protobuf.schema import build_file_descriptor_set

from riskfield.protocol import (
    EsdfGrid,
    Image,
    Message,
    PerceptionFrame,
    RobotState,
    SafetyStatus,
    TrackedObjects,
    ade20k,
)

#: Arrays up to this many elements are written into JSON views as lists; larger ones as a note.
JSON_ARRAY_LIMIT = 4096
PARENT_FRAME, BASE_FRAME = "map", "base_link"

F32, U8, U16 = PackedElementField.FLOAT32, PackedElementField.UINT8, PackedElementField.UINT16


@dataclass(frozen=True)
class View:
    """One viewable record: ``encoding`` is ``protobuf`` (``schema`` = full protobuf name) or ``json``."""

    topic: str
    encoding: str
    schema: str
    data: bytes
    metadata: tuple[tuple[str, str], ...] = ()
    proto: Any = None  # the protobuf message class, for the schema record

    def schema_data(self) -> bytes:
        return schema_data(self.proto) if self.proto is not None else b""


_FDS: dict[str, bytes] = {}


def schema_data(proto_cls: Any) -> bytes:
    """The serialized FileDescriptorSet of a Foxglove protobuf message class (cached)."""
    name = proto_cls.DESCRIPTOR.full_name
    if name not in _FDS:
        _FDS[name] = build_file_descriptor_set(proto_cls).SerializeToString()
    return _FDS[name]


def proto_view(topic: str, msg: Any, metadata: tuple[tuple[str, str], ...] = ()) -> View:
    return View(topic, "protobuf", msg.DESCRIPTOR.full_name, msg.SerializeToString(), metadata, type(msg))


def _stamp(target: Any, m: Message) -> None:
    target.FromNanoseconds(m.header.stamp_ns)


class ImageView:
    """``Image`` → CompressedImage (JPEG), or RawImage when pillow is missing."""

    def __init__(self, jpeg_quality: int = 75):
        self.quality = jpeg_quality
        self.pillow_missing = False

    def __call__(self, topic: str, m: Image) -> list[View]:
        if m.encoding == "jpeg":
            out = CompressedImage(frame_id=m.header.frame_id, format="jpeg", data=m.data)
            _stamp(out.timestamp, m)
            return [proto_view(topic, out)]
        try:
            from PIL import Image as PILImage  # the `sim` extra; optional for the recorder
        except ImportError:
            self.pillow_missing = True
            raw = RawImage(frame_id=m.header.frame_id, width=m.width, height=m.height, encoding="rgb8",
                           step=3 * m.width, data=np.ascontiguousarray(m.data, np.uint8).tobytes())
            _stamp(raw.timestamp, m)
            return [proto_view(topic, raw)]
        buf = io.BytesIO()
        PILImage.fromarray(np.ascontiguousarray(m.data, np.uint8), "RGB").save(buf, "JPEG", quality=self.quality)
        out = CompressedImage(frame_id=m.header.frame_id, format="jpeg", data=buf.getvalue())
        _stamp(out.timestamp, m)
        return [proto_view(topic, out)]


def _cells(distance: np.ndarray, risk: np.ndarray) -> bytes:
    """Packed cells ``distance`` (float32) then ``risk_group`` (uint8), 5 bytes each, in the
    order of the arrays' elements."""
    rec = np.empty(distance.size, dtype=np.dtype([("d", "<f4"), ("g", "u1")]))
    rec["d"] = distance.ravel()
    rec["g"] = risk.ravel()
    return rec.tobytes()


def _grid_fields() -> list[PackedElementField]:
    return [PackedElementField(name="distance", offset=0, type=F32),
            PackedElementField(name="risk_group", offset=4, type=U8)]


def esdf_view(topic: str, m: EsdfGrid) -> list[View]:
    """``EsdfGrid`` → Grid (one layer) or VoxelGrid (several).

    Voxel (i, j, k) has its centre at ``origin + voxel_size·(i, j, k)``; Foxglove places a cell
    by its corner nearest the grid origin, so the pose is ``origin − voxel_size/2`` and the
    data is laid out x fastest (``distance[i, j, k]`` → row j, column i, slice k).
    """
    nx, ny, nz = m.distance.shape
    h = m.voxel_size / 2.0
    meta = (("groups", json.dumps(m.groups)), ("max_distance", repr(m.max_distance)))
    if nz == 1:
        g = Grid(frame_id=m.header.frame_id, column_count=nx, cell_stride=5, row_stride=5 * nx,
                 fields=_grid_fields(), data=_cells(m.distance[:, :, 0].T, m.risk_group[:, :, 0].T))
        g.cell_size.x = g.cell_size.y = m.voxel_size
        g.pose.position.x, g.pose.position.y, g.pose.position.z = m.origin[0] - h, m.origin[1] - h, m.origin[2]
        g.pose.orientation.w = 1.0
        _stamp(g.timestamp, m)
        return [proto_view(topic, g, meta)]
    v = VoxelGrid(frame_id=m.header.frame_id, row_count=ny, column_count=nx, cell_stride=5, row_stride=5 * nx,
                  slice_stride=5 * nx * ny, fields=_grid_fields(),
                  data=_cells(m.distance.transpose(2, 1, 0), m.risk_group.transpose(2, 1, 0)))
    v.cell_size.x = v.cell_size.y = v.cell_size.z = m.voxel_size
    v.pose.position.x, v.pose.position.y, v.pose.position.z = (c - h for c in m.origin)
    v.pose.orientation.w = 1.0
    _stamp(v.timestamp, m)
    return [proto_view(topic, v, meta)]


def pointcloud_view(topic: str, m: PerceptionFrame, stride: int = 8) -> list[View]:
    """Pointmap → decimated world-frame PointCloud with confidence and class id (18 bytes a point)."""
    pts = m.pointmap()[::stride, ::stride].reshape(-1, 3).astype(np.float64)
    conf = m.confidence[::stride, ::stride].ravel()
    cls = m.labels[::stride, ::stride].ravel()
    ok = np.isfinite(pts).all(axis=1)
    T = np.asarray(m.T_WC, dtype=np.float64)
    world = pts[ok] @ T[:3, :3].T + T[:3, 3]
    rec = np.empty(world.shape[0], dtype=np.dtype([("p", "<f4", 3), ("c", "<f4"), ("l", "<u2")]))
    rec["p"], rec["c"], rec["l"] = world, conf[ok], cls[ok]
    pc = PointCloud(frame_id=PARENT_FRAME, point_stride=18, data=rec.tobytes(), fields=[
        PackedElementField(name="x", offset=0, type=F32), PackedElementField(name="y", offset=4, type=F32),
        PackedElementField(name="z", offset=8, type=F32), PackedElementField(name="confidence", offset=12, type=F32),
        PackedElementField(name="class_id", offset=16, type=U16)])
    pc.pose.orientation.w = 1.0
    _stamp(pc.timestamp, m)
    return [proto_view(topic, pc)]


def state_views(topic: str, tf_topic: str, m: RobotState) -> list[View]:
    """``RobotState`` → FrameTransform ``map → base_link`` and PoseInFrame."""
    tf = FrameTransform(parent_frame_id=m.header.frame_id or PARENT_FRAME, child_frame_id=BASE_FRAME)
    pose = PoseInFrame(frame_id=m.header.frame_id or PARENT_FRAME)
    for p in (tf.translation, pose.pose.position):
        p.x, p.y, p.z = m.position
    for q in (tf.rotation, pose.pose.orientation):
        q.x, q.y, q.z, q.w = m.orientation
    _stamp(tf.timestamp, m)
    _stamp(pose.timestamp, m)
    return [proto_view(tf_topic, tf), proto_view(topic, pose)]


def jsonable(obj: Any) -> Any:
    """A msgpack message map as JSON values: arrays (``{dtype, shape, data}``) as nested lists
    when small, otherwise only their dtype and shape; other bytes as their length."""
    if isinstance(obj, dict):
        if isinstance(obj.get("data"), bytes) and "dtype" in obj and "shape" in obj:
            shape = [int(n) for n in obj["shape"]]
            if int(np.prod(shape)) <= JSON_ARRAY_LIMIT:
                values = np.frombuffer(obj["data"], dtype=np.dtype(obj["dtype"])).reshape(shape)
                return {"dtype": obj["dtype"], "shape": shape, "values": values.tolist()}
            return {"dtype": obj["dtype"], "shape": shape, "omitted": True}
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, bytes):
        return {"bytes": len(obj)}
    return obj


def json_view(topic: str, obj: dict, schema: str) -> list[View]:
    return [View(topic, "json", "", json.dumps(jsonable(obj), separators=(",", ":")).encode(),
                 (("riskfield_schema", schema),))]


#: RGBA by risk group id (0 = none, then high, mid, low as the default groups), for scene entities.
GROUP_COLOURS = ((0.6, 0.6, 0.6, 0.8), (0.9, 0.1, 0.1, 0.8), (0.95, 0.55, 0.1, 0.8), (0.95, 0.85, 0.2, 0.8))


def _colour(target: Any, rgba: tuple[float, float, float, float]) -> None:
    target.r, target.g, target.b, target.a = rgba


def _heading(target: Any, v: np.ndarray) -> None:
    """Orientation turning +x (an arrow's axis) onto ``v``: yaw about z, then pitch about y."""
    yaw = float(np.arctan2(v[1], v[0]))
    pitch = float(-np.arctan2(v[2], np.hypot(v[0], v[1])))
    cy, sy, cp, sp = np.cos(yaw / 2), np.sin(yaw / 2), np.cos(pitch / 2), np.sin(pitch / 2)
    target.x, target.y, target.z, target.w = -sy * sp, cy * sp, sy * cp, cy * cp


def objects_view(topic: str, m: TrackedObjects, groups: tuple[str, ...] = ("high", "mid", "low"),
                 height: float = 1.7) -> list[View]:
    """``TrackedObjects`` → SceneUpdate: a cylinder (radius, ``height`` tall, on the object's
    centre), a velocity arrow and a label per object, after deleting every earlier entity."""
    up = SceneUpdate()
    gone = up.deletions.add(type=SceneEntityDeletion.ALL)
    _stamp(gone.timestamp, m)
    for o in m.objects:
        e = up.entities.add(frame_id=m.header.frame_id or PARENT_FRAME, id=f"object/{o.id}")
        _stamp(e.timestamp, m)
        name = ade20k.CLASSES[o.label] if o.label < ade20k.NUM_CLASSES else str(o.label)
        group = groups[o.risk_group - 1] if 0 < o.risk_group <= len(groups) else "none"
        e.metadata.add(key="class", value=name)
        e.metadata.add(key="risk_group", value=group)
        rgba = GROUP_COLOURS[min(o.risk_group, len(GROUP_COLOURS) - 1)]
        c = e.cylinders.add()
        c.pose.position.x, c.pose.position.y, c.pose.position.z = o.position
        c.pose.orientation.w = 1.0
        c.size.x = c.size.y = 2 * max(o.radius, 0.01)
        c.size.z = height
        c.bottom_scale = c.top_scale = 1.0
        _colour(c.color, rgba)
        v = np.asarray(o.velocity, dtype=float)
        speed = float(np.linalg.norm(v))
        if speed > 1e-3:
            a = e.arrows.add(shaft_length=speed, shaft_diameter=0.04, head_length=0.12, head_diameter=0.1)
            a.pose.position.x, a.pose.position.y, a.pose.position.z = o.position
            _heading(a.pose.orientation, v)
            _colour(a.color, (rgba[0], rgba[1], rgba[2], 1.0))
        label = e.texts.add(billboard=True, font_size=14, scale_invariant=True,
                            text=f"{name} #{o.id} ({group}) {speed:.2f} m/s")
        label.pose.position.x, label.pose.position.y = o.position[0], o.position[1]
        label.pose.position.z = o.position[2] + height / 2 + 0.1
        label.pose.orientation.w = 1.0
        _colour(label.color, (1.0, 1.0, 1.0, 1.0))
    return [proto_view(topic, up)]


def _reason(status: SafetyStatus) -> str:
    """Why the filter changes the command, beside h: what the status says of people and the map."""
    why = [f"h = {status.h:.2f} m"]
    if status.yielding:
        why.append("yielding to someone moving")
    if status.evading:
        why.append("evading")
    if status.speed_cap is not None:
        why.append(f"speed cap {status.speed_cap:.2f} m/s")
    if status.scale_uncertain:
        why.append("map scale uncertain")
    return ", ".join(why)


def robot_view(topic: str, m: RobotState, body: float | tuple[float, float],
               status: SafetyStatus | None = None) -> list[View]:
    """The robot's footprint at its pose, coloured by what the filter does: green while it passes
    the command, amber while it intervenes, red while it brakes (``fallback``), with the reason as
    text. ``body``: the platform's (length, width) rectangle, or the radius of a disc for a robot
    described as a point (``protocol.platforms``)."""
    up = SceneUpdate()
    e = up.entities.add(frame_id=m.header.frame_id or PARENT_FRAME, id="robot")
    _stamp(e.timestamp, m)
    if status is None:
        rgba, text = (0.6, 0.6, 0.6, 0.7), "no safety status"
    elif status.fallback:
        rgba, text = (0.9, 0.1, 0.1, 0.8), f"braking: {status.fallback}"
    elif status.intervening:
        rgba, text = (0.95, 0.6, 0.1, 0.8), f"intervening ({_reason(status)})"
    else:
        rgba, text = (0.1, 0.8, 0.3, 0.7), f"passing ({_reason(status)})"
    e.metadata.add(key="safety", value=text)
    if isinstance(body, tuple):
        c = e.cubes.add()
        c.size.x, c.size.y = body
        reach = body[0] / 2
    else:
        c = e.cylinders.add()
        c.size.x = c.size.y = 2 * body
        c.bottom_scale = c.top_scale = 1.0
        reach = body
    c.pose.position.x, c.pose.position.y, c.pose.position.z = m.position
    c.pose.orientation.x, c.pose.orientation.y, c.pose.orientation.z, c.pose.orientation.w = m.orientation
    c.size.z = 0.05
    _colour(c.color, rgba)
    heading = e.arrows.add(shaft_length=reach, shaft_diameter=0.03, head_length=0.06, head_diameter=0.07)
    heading.pose.position.x, heading.pose.position.y, heading.pose.position.z = m.position
    q = heading.pose.orientation
    q.x, q.y, q.z, q.w = m.orientation
    _colour(heading.color, (1.0, 1.0, 1.0, 1.0))
    t = e.texts.add(billboard=True, font_size=14, scale_invariant=True, text=text)
    t.pose.position.x, t.pose.position.y, t.pose.position.z = m.position[0], m.position[1], m.position[2] + 0.4
    t.pose.orientation.w = 1.0
    _colour(t.color, rgba)
    return [proto_view(topic, up)]
