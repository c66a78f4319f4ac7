"""ROS 2 messages ⇄ riskfield messages, serialised by ``rosbags``' type store.

The type store holds the official message definitions of a ROS 2 distribution (Humble or
Jazzy; the types used here are identical in both), so no CDR layout is written by hand here.
zenoh-bridge-ros2dds forwards DDS samples as their raw CDR bytes (4-byte encapsulation header,
then the body), which is exactly what ``Typestore.serialize_cdr``/``deserialize_cdr`` produce
and consume.

Frames (REP 103/105): the body frame is ``base_link`` (x forward, y left, z up), the body frame
of ``VelocityCommand`` too; ``RobotState`` is expressed in the ESDF's frame (``map`` by
default). An Odometry is in ``odom``; it enters the map frame only through a ``map → odom``
transform, never by relabelling.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any, Literal

import numpy as np
from rosbags.typesys import Stores, get_typestore

from riskfield.protocol import EsdfGrid, Header, Image, RobotState, SafetyStatus, VelocityCommand
from riskfield.protocol.jpeg import jpeg_info

from ..geometry.transforms import quat_mul, quat_rotate

TwistType = Literal["Twist", "TwistStamped"]
Distro = Literal["humble", "jazzy"]

TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
TYPENAMES = {"Twist": TWIST, "TwistStamped": TWIST_STAMPED}

# nav2_costmap_2d/include/nav2_costmap_2d/cost_values.hpp: the costmap's 0–255 scale.
NO_INFORMATION, LETHAL_OBSTACLE, INSCRIBED_INFLATED_OBSTACLE, FREE_SPACE = 255, 254, 253, 0


class CdrError(ValueError):
    """A payload that is not a valid CDR sample of the expected ROS 2 type."""


class FrameMismatch(ValueError):
    """A valid message in a frame riskfield must not mix with its own (REP 105)."""


@cache
def typestore(distro: Distro = "jazzy") -> Any:
    return get_typestore({"humble": Stores.ROS2_HUMBLE, "jazzy": Stores.ROS2_JAZZY}[distro])


Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]  # x, y, z, w (ROS order)


@dataclass(frozen=True)
class Transform:
    """One ``geometry_msgs/TransformStamped``: the pose of ``child`` in ``parent``."""

    parent: str
    child: str
    translation: Vec3
    rotation: Quat
    stamp_ns: int = 0


@dataclass(frozen=True)
class Odometry:
    stamp_ns: int
    frame_id: str
    child_frame_id: str
    position: Vec3
    orientation: Quat
    linear: Vec3  # in the child (body) frame
    angular: Vec3


def _finite(*values: float) -> None:
    if not all(math.isfinite(v) for v in values):
        raise CdrError("NaN or Inf in a field that must be finite")


def _stamp_ns(t: Any) -> int:
    return max(0, int(t.sec)) * 1_000_000_000 + int(t.nanosec)


def _vec(v: Any) -> Vec3:
    return (float(v.x), float(v.y), float(v.z))


def _quat(q: Any) -> Quat:
    return (float(q.x), float(q.y), float(q.z), float(q.w))


class RosCodec:
    """Encode/decode the ROS 2 message types the bridge speaks, through one type store."""

    def __init__(self, distro: Distro = "jazzy"):
        self.ts = typestore(distro)
        self.t = self.ts.types

    # -- primitives ---------------------------------------------------------------------------
    def decode(self, raw: bytes, typename: str) -> Any:
        try:
            return self.ts.deserialize_cdr(raw, typename)
        except Exception as exc:  # rosbags raises SerdeError, but guard any parse failure of foreign bytes
            raise CdrError(f"not a CDR {typename}: {exc}") from None

    def encode(self, msg: Any, typename: str) -> bytes:
        return bytes(self.ts.serialize_cdr(msg, typename))

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        sec, nanosec = divmod(max(0, int(stamp_ns)), 1_000_000_000)
        return self.t["std_msgs/msg/Header"](stamp=self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                             frame_id=frame_id)

    def vector3(self, v: Sequence[float]) -> Any:
        return self.t["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quaternion(self, q: Sequence[float]) -> Any:
        return self.t["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    # -- velocity -----------------------------------------------------------------------------
    def encode_twist(self, cmd: VelocityCommand, kind: TwistType = "Twist", stamp_ns: int = 0,
                     frame_id: str = "base_link") -> bytes:
        twist = self.t[TWIST](linear=self.vector3(cmd.linear), angular=self.vector3(cmd.angular))
        if kind == "Twist":
            return self.encode(twist, TWIST)
        return self.encode(self.t[TWIST_STAMPED](header=self.header(stamp_ns, frame_id), twist=twist), TWIST_STAMPED)

    def decode_twist(self, raw: bytes, kind: TwistType = "Twist") -> tuple[Vec3, Vec3, str]:
        """``(linear, angular, frame_id)``; ``frame_id`` is "" for a plain Twist."""
        msg = self.decode(raw, TYPENAMES[kind])
        frame = ""
        if kind == "TwistStamped":
            frame, msg = str(msg.header.frame_id), msg.twist
        lin, ang = _vec(msg.linear), _vec(msg.angular)
        _finite(*lin, *ang)
        return lin, ang, frame

    # -- odometry and TF ----------------------------------------------------------------------
    def encode_odometry(self, o: Odometry) -> bytes:
        t = self.t
        cov = np.zeros(36, np.float64)
        pose = t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](*o.position),
                                             orientation=self.quaternion(o.orientation)),
            covariance=cov)
        twist = t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t[TWIST](linear=self.vector3(o.linear), angular=self.vector3(o.angular)), covariance=cov)
        msg = t[ODOMETRY](header=self.header(o.stamp_ns, o.frame_id), child_frame_id=o.child_frame_id,
                          pose=pose, twist=twist)
        return self.encode(msg, ODOMETRY)

    def decode_odometry(self, raw: bytes) -> Odometry:
        msg = self.decode(raw, ODOMETRY)
        p, tw = msg.pose.pose, msg.twist.twist
        o = Odometry(_stamp_ns(msg.header.stamp), str(msg.header.frame_id), str(msg.child_frame_id),
                     _vec(p.position), _quat(p.orientation), _vec(tw.linear), _vec(tw.angular))
        _finite(*o.position, *o.orientation, *o.linear, *o.angular)
        return o

    def encode_tf(self, transforms: Sequence[Transform]) -> bytes:
        t = self.t
        items = [t["geometry_msgs/msg/TransformStamped"](
            header=self.header(tr.stamp_ns, tr.parent), child_frame_id=tr.child,
            transform=t["geometry_msgs/msg/Transform"](translation=self.vector3(tr.translation),
                                                       rotation=self.quaternion(tr.rotation)))
            for tr in transforms]
        return self.encode(t[TF_MESSAGE](transforms=items), TF_MESSAGE)

    def decode_tf(self, raw: bytes) -> list[Transform]:
        out = []
        for ts in self.decode(raw, TF_MESSAGE).transforms:
            tr = Transform(str(ts.header.frame_id), str(ts.child_frame_id), _vec(ts.transform.translation),
                           _quat(ts.transform.rotation), _stamp_ns(ts.header.stamp))
            _finite(*tr.translation, *tr.rotation)
            out.append(tr)
        return out

    # -- map and status -----------------------------------------------------------------------
    def encode_occupancy_grid(self, esdf: EsdfGrid, data: np.ndarray, stamp_ns: int) -> bytes:
        """``data`` (nx × ny int8, from :func:`costmap`) as an OccupancyGrid in the ESDF's frame.

        OccupancyGrid cells are row-major with x fastest (``data[x + y·width]``) and
        ``info.origin`` is the *corner* of cell (0, 0), whereas the ESDF's origin is the
        *centre* of voxel (0, 0, 0): hence the half-voxel shift.
        """
        t = self.t
        nx, ny = data.shape
        h = esdf.voxel_size / 2.0
        origin = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=esdf.origin[0] - h, y=esdf.origin[1] - h, z=esdf.origin[2]),
            orientation=self.quaternion((0.0, 0.0, 0.0, 1.0)))
        sec, nanosec = divmod(max(0, int(stamp_ns)), 1_000_000_000)
        info = t["nav_msgs/msg/MapMetaData"](map_load_time=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                             resolution=float(esdf.voxel_size), width=nx, height=ny, origin=origin)
        msg = t[OCCUPANCY_GRID](header=self.header(stamp_ns, esdf.header.frame_id), info=info,
                                data=np.ascontiguousarray(data.T).reshape(-1).astype(np.int8))
        return self.encode(msg, OCCUPANCY_GRID)

    def encode_diagnostics(self, status: SafetyStatus, hardware_id: str, stamp_ns: int) -> bytes:
        t = self.t
        Status, KeyValue = t["diagnostic_msgs/msg/DiagnosticStatus"], t["diagnostic_msgs/msg/KeyValue"]
        level, message = diagnostic_level(status)
        values = [KeyValue(key=k, value=v) for k, v in (
            ("h", f"{status.h:.4f}"), ("risk_group", str(status.risk_group)),
            ("intervening", str(status.intervening).lower()), ("fallback", status.fallback or ""),
            ("solve_us", f"{status.solve_us:.1f}"), ("esdf_age_ms", f"{status.esdf_age_ms:.1f}"))]
        st = Status(level=level, name="riskfield: safety filter", message=message, hardware_id=hardware_id,
                    values=values)
        return self.encode(t[DIAGNOSTIC_ARRAY](header=self.header(stamp_ns, ""), status=[st]), DIAGNOSTIC_ARRAY)


def diagnostic_level(status: SafetyStatus) -> tuple[int, str]:
    """``DiagnosticStatus`` level (0 OK, 1 WARN, 2 ERROR) and message of a ``SafetyStatus``:
    braking for a fail-safe reason is an error, an intervening filter a warning."""
    if status.fallback:
        return 2, f"braking: {status.fallback}"
    if status.intervening:
        return 1, "intervening"
    return 0, "passing the reference through"


# -- frames -------------------------------------------------------------------------------------
def _normalised(q: Sequence[float]) -> np.ndarray:
    a = np.asarray(q, dtype=float)
    n = float(np.linalg.norm(a))
    if not math.isfinite(n) or n < 1e-6:
        raise ValueError("orientation is not a quaternion")
    return a / n


def odometry_to_state(o: Odometry, map_frame: str, map_T_odom: Transform | None = None) -> RobotState:
    """The ``RobotState`` in ``map_frame`` of an Odometry.

    With ``o.frame_id == map_frame`` the pose is taken as is; otherwise ``map_T_odom`` (the
    pose of ``o.frame_id`` in ``map_frame``) composes it: :math:`p_m = R_{mo} p_o + t_{mo}`,
    :math:`q_m = q_{mo} ⊗ q_o`. The body-frame twist is rotated into the map frame by
    :math:`q_m`. Any other frame raises ``FrameMismatch`` naming both frames: a state is never
    relabelled into a frame it is not in.
    """
    q = _normalised(o.orientation)
    p = np.asarray(o.position, dtype=float)
    if o.frame_id != map_frame:
        if map_T_odom is None or map_T_odom.parent != map_frame or map_T_odom.child != o.frame_id:
            raise FrameMismatch(f"odometry frame {o.frame_id!r} is not the map frame {map_frame!r} "
                             f"and no {map_frame} → {o.frame_id} transform is known")
        qt = _normalised(map_T_odom.rotation)
        p = quat_rotate(qt, p) + np.asarray(map_T_odom.translation, dtype=float)
        q = _normalised(quat_mul(qt, q))
    return RobotState(
        header=Header(stamp_ns=o.stamp_ns, frame_id=map_frame),
        position=tuple(float(c) for c in p),
        orientation=tuple(float(c) for c in q),
        linear_velocity=tuple(float(c) for c in quat_rotate(q, o.linear)),
        angular_velocity=tuple(float(c) for c in quat_rotate(q, o.angular)),
    )


def state_to_tf(state: RobotState, odom_frame: str, base_frame: str) -> list[Transform]:
    """REP-105 transforms of riskfield's state: ``odom → base`` is the state's pose; when the
    state's frame (the map) is not ``odom_frame``, ``map → odom`` is published as the identity,
    because riskfield's state has no separate drift correction (it *is* the map-frame pose)."""
    frame = state.header.frame_id
    out = []
    if frame != odom_frame:
        out.append(Transform(frame, odom_frame, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), state.header.stamp_ns))
    out.append(Transform(odom_frame, base_frame, state.position, state.orientation, state.header.stamp_ns))
    return out


# -- costmap ------------------------------------------------------------------------------------
def _translation_table() -> np.ndarray:
    """Costmap (0–255) → OccupancyGrid (−1–100), as Nav2 publishes its costmaps
    (nav2_costmap_2d/src/costmap_2d_publisher.cpp, ``Costmap2DPublisher``'s
    ``cost_translation_table_``): 0 → 0, 253 → 99, 254 → 100, 255 → −1, and 1–252 scaled
    linearly onto 1–98."""
    table = np.empty(256, np.int8)
    i = np.arange(1, 253)
    table[1:253] = 1 + (97 * (i - 1)) // 251
    table[FREE_SPACE], table[INSCRIBED_INFLATED_OBSTACLE] = 0, 99
    table[LETHAL_OBSTACLE], table[NO_INFORMATION] = 100, -1
    return table


COST_TRANSLATION = _translation_table()


def nav2_cost(distance: np.ndarray, scaling: np.ndarray, inscribed_radius: float,
              inflation_radius: float) -> np.ndarray:
    """Nav2's inflation cost (0–255 scale) of a signed distance ``d`` (m) to the inflated
    obstacle set, after ``InflationLayer::computeCost``
    (nav2_costmap_2d/include/nav2_costmap_2d/inflation_layer.hpp):

    .. math::
        c(d) = \\begin{cases} 254 & d ≤ 0 \\\\ 253 & 0 < d ≤ r_{in} \\\\
               ⌊252\\,e^{-k (d - r_{in})}⌋ & r_{in} < d ≤ r_{inf} \\\\ 0 & d > r_{inf} \\end{cases}

    Nav2 measures ``d`` from obstacle cell centres (lethal only at d = 0); the ESDF's zero level
    set is the inflated obstacle's boundary, so lethal is ``d ≤ 0``. ``k`` is per cell (the
    scaling factor of the risk group of the nearest obstacle). Non-finite distances are unknown.
    """
    d = np.asarray(distance, dtype=np.float64)
    known = np.isfinite(d)
    dd = np.where(known, d, 0.0)
    decay = np.floor((INSCRIBED_INFLATED_OBSTACLE - 1) * np.exp(-scaling * (dd - inscribed_radius)))
    cost = np.where(dd > inflation_radius, FREE_SPACE, decay)
    cost = np.where(dd <= inscribed_radius, INSCRIBED_INFLATED_OBSTACLE, cost)
    cost = np.where(dd <= 0.0, LETHAL_OBSTACLE, cost)
    return np.where(known, cost, NO_INFORMATION).astype(np.uint8)


def costmap(esdf: EsdfGrid, scaling_by_group: dict[str, float], default_scaling: float, inscribed_radius: float,
            inflation_radius: float) -> np.ndarray:
    """The OccupancyGrid values (nx × ny int8) of a 2-D ESDF slice (nz = 1): Nav2's costmap
    values through Nav2's costmap → OccupancyGrid translation (100 lethal, 99 inscribed,
    1–98 decaying, 0 free, −1 unknown)."""
    if esdf.distance.shape[2] != 1:
        raise ValueError(f"the costmap needs a 2-D ESDF slice (nz = 1), got nz = {esdf.distance.shape[2]}")
    factors = np.array([default_scaling] + [scaling_by_group.get(g, default_scaling) for g in esdf.groups])
    k = factors[esdf.risk_group[:, :, 0]]
    return COST_TRANSLATION[nav2_cost(esdf.distance[:, :, 0], k, inscribed_radius, inflation_radius)]


# -- camera -------------------------------------------------------------------------------------
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"

#: sensor_msgs image encodings (ros2/common_interfaces, sensor_msgs/include/sensor_msgs/image_encodings.hpp)
#: the bridge turns into rgb8: bytes per pixel and where R, G, B sit in a pixel.
IMAGE_LAYOUTS: dict[str, tuple[int, tuple[int, int, int]]] = {
    "rgb8": (3, (0, 1, 2)), "bgr8": (3, (2, 1, 0)), "rgba8": (4, (0, 1, 2)), "bgra8": (4, (2, 1, 0)),
    "mono8": (1, (0, 0, 0)),
}

STAMP_WINDOW_NS = (10_000_000_000, 1_000_000_000)
"""A ROS stamp this far in the past / future of the wall clock is taken as the capture time; outside it
(simulation time, an unsynchronised driver) the arrival time is (``Image`` stamps are wall clock)."""

Intrinsics = tuple[float, float, float, float]


def image_stamp(ros_ns: int, now_ns: int) -> tuple[int, bool]:
    """``(stamp, from_ros)``: the ROS header stamp when it is on the wall clock, else ``now_ns``."""
    past, future = STAMP_WINDOW_NS
    if now_ns - past <= ros_ns <= now_ns + future:
        return ros_ns, True
    return now_ns, False


def decode_image(codec: RosCodec, raw: bytes, now_ns: int, intrinsics: Intrinsics | None = None) -> tuple[Image, bool]:
    """A ``sensor_msgs/Image`` as an rgb8 ``Image`` (rows as ``step`` pads them; 8-bit RGB, BGR,
    RGBA, BGRA or mono), and whether its stamp is the ROS one. ``CdrError`` for bad CDR, ``ValueError``
    for an encoding or a size the bytes do not hold."""
    msg = codec.decode(raw, IMAGE)
    enc, w, h, step = str(msg.encoding), int(msg.width), int(msg.height), int(msg.step)
    if enc not in IMAGE_LAYOUTS:
        raise ValueError(f"image encoding {enc!r} is not supported; known: {', '.join(IMAGE_LAYOUTS)}")
    channels, rgb_index = IMAGE_LAYOUTS[enc]
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if w <= 0 or h <= 0 or step < w * channels or data.size < step * h:
        raise ValueError(f"a {w}x{h} {enc} image with step {step} does not fit in {data.size} bytes")
    pixels = data[: step * h].reshape(h, step)[:, : w * channels].reshape(h, w, channels)
    rgb = np.ascontiguousarray(pixels[:, :, list(rgb_index)])
    stamp, from_ros = image_stamp(_stamp_ns(msg.header.stamp), now_ns)
    return Image(header=Header(stamp_ns=stamp, frame_id=str(msg.header.frame_id)), encoding="rgb8", width=w,
                 height=h, data=rgb, intrinsics=intrinsics), from_ros


def decode_compressed_image(codec: RosCodec, raw: bytes, now_ns: int,
                            intrinsics: Intrinsics | None = None) -> tuple[Image, bool]:
    """A ``sensor_msgs/CompressedImage`` holding a JPEG (``format`` "jpeg", or image_transport's
    "bgr8; jpeg compressed bgr8") as a ``jpeg`` ``Image``, its bytes untouched. A JPEG a decoder
    could not read alone (no Huffman tables) or another format (png) is a ``ValueError``."""
    msg = codec.decode(raw, COMPRESSED_IMAGE)
    fmt = str(msg.format).lower()
    if "jpeg" not in fmt and "jpg" not in fmt:
        raise ValueError(f"compressed format {msg.format!r}: only jpeg is carried (Image encoding jpeg)")
    data = bytes(np.asarray(msg.data, dtype=np.uint8))
    info = jpeg_info(data)
    if not info.has_huffman_tables:
        raise ValueError("a JPEG without Huffman tables (raw UVC MJPEG): republish it decoded")
    stamp, from_ros = image_stamp(_stamp_ns(msg.header.stamp), now_ns)
    return Image(header=Header(stamp_ns=stamp, frame_id=str(msg.header.frame_id)), encoding="jpeg",
                 width=info.width, height=info.height, data=data, intrinsics=intrinsics), from_ros


@dataclass(frozen=True)
class CameraInfo:
    width: int
    height: int
    distortion_model: str
    d: tuple[float, ...]
    k: tuple[float, ...]
    r: tuple[float, ...]
    p: tuple[float, ...]

    def intrinsics(self, rectified: bool) -> Intrinsics | None:
        """The pinhole intrinsics of the images this camera_info describes, or None: for rectified
        images (image_proc's ``image_rect``) the projection P (REP 104: P maps the rectified image); for
        raw images K, but only when there is no distortion (a distorted image has no pinhole model,
        so perception gets none). An uncalibrated camera (K = 0) has none."""
        if rectified:
            fx, fy, cx, cy = self.p[0], self.p[5], self.p[2], self.p[6]
        else:
            if any(c != 0 for c in self.d):
                return None
            fx, fy, cx, cy = self.k[0], self.k[4], self.k[2], self.k[5]
        if not (fx > 0 and fy > 0 and all(math.isfinite(v) for v in (fx, fy, cx, cy))):
            return None
        return (float(fx), float(fy), float(cx), float(cy))


def decode_camera_info(codec: RosCodec, raw: bytes) -> CameraInfo:
    msg = codec.decode(raw, CAMERA_INFO)
    d = tuple(float(v) for v in np.asarray(msg.d, dtype=float).reshape(-1))
    k = tuple(float(v) for v in np.asarray(msg.k, dtype=float).reshape(-1))
    r = tuple(float(v) for v in np.asarray(msg.r, dtype=float).reshape(-1))
    p = tuple(float(v) for v in np.asarray(msg.p, dtype=float).reshape(-1))
    if len(k) != 9 or len(r) != 9 or len(p) != 12:
        raise CdrError("CameraInfo k, r, p must hold 9, 9 and 12 numbers")
    _finite(*d, *k, *r, *p)
    return CameraInfo(int(msg.width), int(msg.height), str(msg.distortion_model), d, k, r, p)
