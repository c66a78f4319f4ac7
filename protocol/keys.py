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
