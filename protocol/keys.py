"""Key expressions of the wire contract: ``{prefix}/{robot}/...``."""

from __future__ import annotations

import re
from dataclasses import dataclass

from .messages import (
    Alignment,
    CommandLock,
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
    "cmd/lock": CommandLock,  # additive: locks on the cmd/ref arbitration (twist_mux's lock topics)
    "safety/status": SafetyStatus,
    "nav/goal": NavGoal,
    "config/risk": RiskConfig,
    "sim/truth": PerceptionFrame,
    "limo/diagnostics": LimoDiagnostics,  # simulation only: perfect pointmap and labels, stamped like the image
    "map/objects": TrackedObjects,  # additive: tracked people/animals with velocities, stamped like map/esdf
    "sim/actors": SimActors,  # additive, simulation only: ground truth of the moving objects
    "perception/alignment": Alignment,  # additive: SLAM world → odometry similarity, with its uncertainty
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
    "cmd/lock": Qos("real_time", drop=False, express=True),  # sent on a change: must arrive
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
    "perception/alignment": Qos("data_high"),  # small; bounds the filter's distances, with the map
}
STATUS_QOS = Qos("background")


def qos_of(relative: str | None) -> Qos:
    """The QoS of a key given relative to its robot (``Keys.relative``); ``Qos()`` for any other."""
    if relative is None:
        return Qos()
    if relative.startswith("status/"):
        return STATUS_QOS
    return QOS.get(base_of(relative), Qos())


#: Where a role runs: ``robot`` (the robot's computer and its own router) or ``server`` (the site
#: its router dials). The routers forward only what one site produces and the other consumes.
SITES = ("robot", "server")


@dataclass(frozen=True)
class Role:
    """One identity of a deployment, per robot: a user name and a certificate common name that the
    routers' access control knows (``{robot}.{role}``)."""

    site: str
    service: str | None = None  # the node whose status/alive keys it owns; None: not a riskfield node

    def __post_init__(self) -> None:
        if self.site not in SITES:
            raise ValueError(f"site {self.site!r}: use one of {', '.join(SITES)}")


#: Every role of a deployment. ``operator`` is a person's tools (dashboards, ``riskfield replay``,
#: goals, risk configurations); ``planner`` an external client of the map; ``record`` and ``viewer``
#: read everything of their robot.
ROLES: dict[str, Role] = {
    "safety-filter": Role("robot", "safety-filter"),
    "limo": Role("robot", "limo"),
    "mavlink": Role("robot", "mavlink"),
    "joystick": Role("robot", "joystick"),
    "teleop": Role("robot", "keyboard"),
    "camera": Role("robot", "camera"),
    "ros2-bridge": Role("robot", "ros2-bridge"),
    "zenoh-bridge-ros2dds": Role("robot"),
    "perception": Role("server", "perception"),
    "mapping": Role("server", "mapping"),
    "simulator": Role("server", "simulator"),
    "navigator": Role("server", "navigator"),
    "operator": Role("server", "operator"),
    "relay": Role("server", "relay"),
    "record": Role("server", "record"),
    "viewer": Role("server", "viewer"),
    "planner": Role("server"),
}

#: Roles that read every key of their robot (``{prefix}/{robot}/**``).
READ_ALL = ("operator", "record", "viewer")


@dataclass(frozen=True)
class Route:
    """Who puts a key and who takes it (subscribes, or queries when the key is a queryable)."""

    producers: tuple[str, ...]
    consumers: tuple[str, ...] = ()


#: Relative key → its producers and consumers: the one declaration the routers' access control is
#: generated from (``riskfield acl``, ``services/runtime/acl.py``). A key or role missing here is
#: refused by the secure routers. ``map/esdf/query``'s producer serves it, its consumers query it.
#: Besides these, each role with a service puts its own ``status/{service}`` and declares its own
#: ``alive/{service}``, and ``READ_ALL`` roles read every key.
ROUTES: dict[str, Route] = {
    "camera/image": Route(("simulator", "camera"), ("perception", "ros2-bridge")),
    "camera/depth": Route(("simulator",), ("perception",)),
    "perception/frame": Route(("perception",), ("mapping", "camera")),  # camera: pace=perception's acks
    "perception/alignment": Route(("perception",), ("mapping", "safety-filter")),
    "map/esdf": Route(("mapping",), ("safety-filter", "navigator", "ros2-bridge", "planner")),
    "map/esdf3d": Route(("mapping",), ("planner",)),
    "map/esdf/query": Route(("mapping",), ("navigator", "planner")),
    "map/objects": Route(("mapping",), ("safety-filter", "navigator", "planner")),
    "state": Route(("simulator", "limo", "mavlink", "ros2-bridge"),
                   ("perception", "mapping", "safety-filter", "navigator", "ros2-bridge", "planner")),
    "state/relocalise": Route(("simulator",), ("mapping", "safety-filter")),
    "cmd/ref": Route(("joystick", "teleop", "navigator", "operator", "ros2-bridge"), ("safety-filter",)),
    "cmd/lock": Route(("joystick", "teleop", "operator"), ("safety-filter",)),
    "cmd/safe": Route(("safety-filter",), ("limo", "mavlink", "simulator", "ros2-bridge")),
    "safety/status": Route(("safety-filter",), ("ros2-bridge", "joystick")),
    "nav/goal": Route(("operator",), ("navigator",)),
    "config/risk": Route(("operator",), ("mapping", "safety-filter")),
    "sim/truth": Route(("simulator",), ("perception",)),
    "sim/spawn": Route(("operator",), ("simulator",)),
    "sim/reset": Route(("operator",), ("simulator",)),
    "sim/actors": Route(("simulator",), ()),
    "limo/diagnostics": Route(("limo",), ()),
    "relay/**": Route(("relay",), ()),
}

#: Who speaks for which ``cmd/ref`` and ``cmd/lock`` source: role → the source names it puts
#: ``cmd/ref/<source>`` and ``cmd/lock/<source>`` under (additive keys). The key names the source,
#: the filter refuses a message that names another, and the routers' access control lets only
#: this role put that key: on a secure site no identity can claim another's priority or release
#: another's lock. The plain ``cmd/ref`` / ``cmd/lock`` trust the message's declared
#: ``source``; they stay in the contract for loopback stacks and no role of a secure site puts them.
REF_SOURCES: dict[str, tuple[str, ...]] = {
    "joystick": ("joystick",), "teleop": ("keyboard",), "navigator": ("navigator",), "operator": ("operator",),
    "ros2-bridge": ("ros2/**",),  # ros2/<input name>: one per cmd_vel input of the bridge (docs/ros2.md)
}
LOCK_SOURCES: dict[str, tuple[str, ...]] = {"joystick": ("joystick",), "teleop": ("keyboard",),
                                            "operator": ("operator",)}

#: Keys whose last chunks may name a source (``REF_SOURCES``, ``LOCK_SOURCES``).
SOURCED = ("cmd/ref", "cmd/lock")


def _sourced(base: str, sources: dict[str, tuple[str, ...]]) -> dict[str, Route]:
    consumers = ROUTES[base].consumers
    routes = {f"{base}/{name}": Route((role,), consumers) for role, names in sources.items() for name in names}
    # The plain key: put by no role; and the consumers' one subscription on every source.
    return {**routes, base: Route((), consumers), f"{base}/**": Route((), consumers)}


ROUTES.update(_sourced("cmd/ref", REF_SOURCES))
ROUTES.update(_sourced("cmd/lock", LOCK_SOURCES))


def base_of(relative: str) -> str:
    """The contract key a relative key is an instance of: ``cmd/ref/joystick`` → ``cmd/ref``."""
    for base in SOURCED:
        if relative.startswith(base + "/"):
            return base
    return relative


def source_of(relative: str) -> str | None:
    """The source a ``SOURCED`` key names (``cmd/ref/ros2/nav`` → ``ros2/nav``); None for the plain
    key or any other."""
    base = base_of(relative)
    return relative[len(base) + 1:] if base != relative else None

#: Keys outside ``{prefix}/`` that the ROS 2 bridges put and read, relative to the robot's ROS
#: namespace (``{robot}/...``; docs/ros2.md).
ROS_ROUTES: dict[str, Route] = {
    "cmd_vel": Route(("ros2-bridge",), ("zenoh-bridge-ros2dds",)),
    "riskfield/costmap": Route(("ros2-bridge",), ("zenoh-bridge-ros2dds",)),
    "diagnostics": Route(("ros2-bridge",), ("zenoh-bridge-ros2dds",)),
    "tf": Route(("ros2-bridge", "zenoh-bridge-ros2dds"), ("ros2-bridge", "zenoh-bridge-ros2dds")),
    "cmd_vel_smoothed": Route(("zenoh-bridge-ros2dds",), ("ros2-bridge",)),
    "odom": Route(("zenoh-bridge-ros2dds",), ("ros2-bridge",)),
    "tf_static": Route(("zenoh-bridge-ros2dds",), ("ros2-bridge",)),
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
    state_relocalise = property(lambda self: self.key("state/relocalise"))
    cmd_ref = property(lambda self: self.key("cmd/ref"))
    cmd_safe = property(lambda self: self.key("cmd/safe"))
    cmd_lock = property(lambda self: self.key("cmd/lock"))
    cmd_ref_any = property(lambda self: self.key("cmd/ref/**"))  # every source, the plain key too
    cmd_lock_any = property(lambda self: self.key("cmd/lock/**"))

    def cmd_ref_of(self, source: str) -> str:
        """``cmd/ref/<source>``: the key a source's references go on (``REF_SOURCES``)."""
        return self.key(f"cmd/ref/{_check(source, 'source', allow_slash=True)}")

    def cmd_lock_of(self, source: str) -> str:
        """``cmd/lock/<source>``: the key a source's locks go on (``LOCK_SOURCES``)."""
        return self.key(f"cmd/lock/{_check(source, 'source', allow_slash=True)}")
    safety_status = property(lambda self: self.key("safety/status"))
    nav_goal = property(lambda self: self.key("nav/goal"))
    risk_config = property(lambda self: self.key("config/risk"))
    sim_truth = property(lambda self: self.key("sim/truth"))
    sim_spawn = property(lambda self: self.key("sim/spawn"))
    sim_actors = property(lambda self: self.key("sim/actors"))
    sim_reset = property(lambda self: self.key("sim/reset"))
    objects = property(lambda self: self.key("map/objects"))
    alignment = property(lambda self: self.key("perception/alignment"))

    def alive(self, service: str) -> str:
        return self.key(f"alive/{_check(service, 'service', False)}")

    def status(self, service: str) -> str:
        return self.key(f"status/{_check(service, 'service', False)}")

    def relative(self, key: str) -> str | None:
        """The part after ``{prefix}/{robot}/``, or None for a key of another robot."""
        head = self.root + "/"
        return key[len(head):] if key.startswith(head) else None
