"""Reference ROS 2 message classes built with pycdr2 (CycloneDDS's IDL package), written from
the official .msg definitions (common_interfaces, rcl_interfaces, geometry2 for tf2_msgs), to
check the bridge's CDR (serialised by rosbags) against an independent implementation. Module
level: pycdr2 resolves names here. ROS ``byte`` is IDL ``octet`` (uint8)."""

from dataclasses import dataclass

from pycdr2 import IdlStruct
from pycdr2.types import array, float32, float64, int8, int32, sequence, uint8, uint32


@dataclass
class Time(IdlStruct, typename="builtin_interfaces/msg/Time"):
    sec: int32
    nanosec: uint32


@dataclass
class Hdr(IdlStruct, typename="std_msgs/msg/Header"):
    stamp: Time
    frame_id: str


@dataclass
class Vec(IdlStruct, typename="geometry_msgs/msg/Vector3"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quat(IdlStruct, typename="geometry_msgs/msg/Quaternion"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs/msg/Pose"):
    position: Vec
    orientation: Quat


@dataclass
class PoseCov(IdlStruct, typename="geometry_msgs/msg/PoseWithCovariance"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class Twist(IdlStruct, typename="geometry_msgs/msg/Twist"):
    linear: Vec
    angular: Vec


@dataclass
class TwistCov(IdlStruct, typename="geometry_msgs/msg/TwistWithCovariance"):
    twist: Twist
    covariance: array[float64, 36]


@dataclass
class Odom(IdlStruct, typename="nav_msgs/msg/Odometry"):
    header: Hdr
    child_frame_id: str
    pose: PoseCov
    twist: TwistCov


@dataclass
class Point(IdlStruct, typename="geometry_msgs/msg/Point"):
    x: float64
    y: float64
    z: float64


@dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs/msg/TwistStamped"):
    header: Hdr
    twist: Twist


@dataclass
class Transform(IdlStruct, typename="geometry_msgs/msg/Transform"):
    translation: Vec
    rotation: Quat


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs/msg/TransformStamped"):
    header: Hdr
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs/msg/TFMessage"):
    transforms: sequence[TransformStamped]


@dataclass
class MapPose(IdlStruct, typename="geometry_msgs/msg/Pose"):
    position: Point
    orientation: Quat


@dataclass
class MapMetaData(IdlStruct, typename="nav_msgs/msg/MapMetaData"):
    map_load_time: Time
    resolution: float32
    width: uint32
    height: uint32
    origin: MapPose


@dataclass
class OccupancyGrid(IdlStruct, typename="nav_msgs/msg/OccupancyGrid"):
    header: Hdr
    info: MapMetaData
    data: sequence[int8]


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs/msg/KeyValue"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs/msg/DiagnosticStatus"):
    level: uint8
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs/msg/DiagnosticArray"):
    header: Hdr
    status: sequence[DiagnosticStatus]
