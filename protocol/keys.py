"""Key expressions of the wire contract: ``{prefix}/{robot}/...``."""

from __future__ import annotations

import re
from dataclasses import dataclass

from .messages import (
    DepthImage,
    DistanceQuery,
    EsdfGrid,
    Image,
    LimoDiagnostics,
    Message,
    NavGoal,
    PerceptionFrame,
    RobotState,
    SafetyStatus,
    SimActors,
    TrackedObjects,
    VelocityCommand,
)
from .risk import RiskConfig

_CHUNK = re.compile(r"^[A-Za-z0-9_\-.~+=@:]+$")

#: Relative key → the message published on it (queries: the request type).
TOPICS: dict[str, type[Message]] = {
    "camera/image": Image,
    "camera/depth": DepthImage,  # additive: depth registered to camera/image (same stamp), RGB-D robots
    "perception/frame": PerceptionFrame,
    "map/esdf": EsdfGrid,
    "map/esdf3d": EsdfGrid,  # the 3-D grid when map/esdf carries the ground robot's 2-D slice
    "map/esdf/query": DistanceQuery,
    "state": RobotState,
    "state/relocalise": RobotState,  # additive: an announced jump of the state (relocalisation, reset)
    "cmd/ref": VelocityCommand,
    "cmd/safe": VelocityCommand,
    "safety/status": SafetyStatus,
    "nav/goal": NavGoal,
    "config/risk": RiskConfig,
    "sim/truth": PerceptionFrame,
    "limo/diagnostics": LimoDiagnostics,  # simulation only: perfect pointmap and labels, stamped like the image
    "map/objects": TrackedObjects,  # additive: tracked people/animals with velocities, stamped like map/esdf
    "sim/actors": SimActors,  # additive, simulation only: ground truth of the moving objects
}


@dataclass(frozen=True)
class Qos:
    """How a key crosses a congested link: Zenoh's per-sample QoS, as plain names so that the wire
    contract does not import zenoh (the runtime maps them onto ``zenoh.Priority`` and
    ``zenoh.CongestionControl`` where it declares its publishers).

    ``priority`` is one of Zenoh's priorities by name (``real_time`` highest … ``background``); ``drop``
    lets a full transmission queue drop the sample (the newest value supersedes it anyway) instead
    of blocking the publisher; ``express`` sends it at once instead of batching it with others."""

    priority: str = "data"
    drop: bool = True
    express: bool = False

    def __post_init__(self) -> None:
        if self.priority not in PRIORITIES:
            raise ValueError(f"priority {self.priority!r}: use one of {', '.join(PRIORITIES)}")


#: Zenoh's priorities, highest first (zenoh ``Priority``: REAL_TIME … BACKGROUND).
PRIORITIES = ("real_time", "interactive_high", "interactive_low", "data_high", "data", "data_low", "background")

#: Relative key → its QoS, the one declaration of the link policy: commands and state above maps,
#: maps above images and frames; what only the newest value matters for may be dropped on a full
#: queue, a goal or a risk configuration (sent once) must arrive. Keys not listed get ``Qos()``;
#: ``status/*`` (every node's counters) is ``STATUS_QOS``.
QOS: dict[str, Qos] = {
    "cmd/safe": Qos("real_time", express=True),
    "cmd/ref": Qos("real_time", express=True),
    "state": Qos("interactive_high", express=True),
    "state/relocalise": Qos("interactive_high", drop=False, express=True),  # sent once per jump: must arrive
    "safety/status": Qos("interactive_low"),
    "nav/goal": Qos("interactive_low", drop=False),
    "config/risk": Qos("interactive_low", drop=False),
    "map/esdf": Qos("data_high"),
    "map/objects": Qos("data_high"),
    "map/esdf3d": Qos("data"),
    "camera/image": Qos("data_low"),
    "camera/depth": Qos("data_low"),
    "perception/frame": Qos("data_low"),
    "sim/truth": Qos("data_low"),
    "limo/diagnostics": Qos("background"),
}
STATUS_QOS = Qos("background")


def qos_of(relative: str | None) -> Qos:
    """The QoS of a key given relative to its robot (``Keys.relative``); ``Qos()`` for any other."""
    if relative is None:
        return Qos()
    if relative.startswith("status/"):
        return STATUS_QOS
    return QOS.get(relative, Qos())


def _check(value: str, what: str, allow_slash: bool) -> str:
    chunks = value.split("/") if allow_slash else [value]
    if not value or not all(_CHUNK.match(c) for c in chunks):
        raise ValueError(f"{what} {value!r}: use letters, digits and -_.~+=@: (no wildcards, no empty chunks)")
    return value


@dataclass(frozen=True)
class Keys:
    """Builds every key of one robot. ``prefix`` may hold '/' (e.g. ``site1/rf``)."""

    robot: str = "limo1"
    prefix: str = "rf"

    def __post_init__(self) -> None:
        _check(self.prefix, "prefix", allow_slash=True)
        _check(self.robot, "robot id", allow_slash=False)

    def key(self, relative: str) -> str:
        return f"{self.prefix}/{self.robot}/{relative}"

    @property
    def root(self) -> str:
        return f"{self.prefix}/{self.robot}"

    camera_image = property(lambda self: self.key("camera/image"))
    camera_depth = property(lambda self: self.key("camera/depth"))
    perception_frame = property(lambda self: self.key("perception/frame"))
    esdf = property(lambda self: self.key("map/esdf"))
    esdf_query = property(lambda self: self.key("map/esdf/query"))
    esdf3d = property(lambda self: self.key("map/esdf3d"))
    state = property(lambda self: self.key("state"))
    state_relocalise = property(lambda self: self.key("state/relocalise"))
    cmd_ref = property(lambda self: self.key("cmd/ref"))
    cmd_safe = property(lambda self: self.key("cmd/safe"))
    safety_status = property(lambda self: self.key("safety/status"))
    nav_goal = property(lambda self: self.key("nav/goal"))
    risk_config = property(lambda self: self.key("config/risk"))
    sim_truth = property(lambda self: self.key("sim/truth"))
    sim_spawn = property(lambda self: self.key("sim/spawn"))
    sim_actors = property(lambda self: self.key("sim/actors"))
    sim_reset = property(lambda self: self.key("sim/reset"))
    objects = property(lambda self: self.key("map/objects"))

    def alive(self, service: str) -> str:
        return self.key(f"alive/{_check(service, 'service', False)}")

    def status(self, service: str) -> str:
        return self.key(f"status/{_check(service, 'service', False)}")

    def relative(self, key: str) -> str | None:
        """The part after ``{prefix}/{robot}/``, or None for a key of another robot."""
        head = self.root + "/"
        return key[len(head):] if key.startswith(head) else None
