"""Reference ROS 2 message classes built with pycdr2 (CycloneDDS's IDL package), to check our
CDR bytes against an independent implementation. Module level: pycdr2 resolves names here."""

from dataclasses import dataclass

from pycdr2 import IdlStruct
from pycdr2.types import array, float64, int32, uint32


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
