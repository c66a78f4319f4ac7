"""ROS 2 bridge node: riskfield as a drop-in safety layer between Nav2's controller and the base,
through zenoh-bridge-ros2dds (docs/ros2.md).

Keys follow zenoh-bridge-ros2dds (eclipse-zenoh/zenoh-plugin-ros2dds,
``ros2_name_to_key_expr`` in zenoh-plugin-ros2dds/src/ros2_utils.rs): a ROS topic ``/ns/topic``
is the Zenoh key ``ns/topic`` (the bridge's ``namespace`` prefixed, the leading ``/`` dropped,
also for absolute names such as ``/tf``); payloads are the raw CDR samples, put here with the
``application/cdr`` encoding.

In:  velocity input (Nav2's ``cmd_vel_smoothed``) and an optional teleop input, arbitrated like
     twist_mux → ``cmd/ref``; ``odom`` (+ ``tf``/``tf_static`` for ``map → odom``) → ``state`` in
     the ESDF's frame; a state in another frame is refused and counted; optionally a camera's
     Image / CompressedImage (JPEG) + CameraInfo → ``camera/image`` (docs/ros2.md, "Camera images").
Out: ``cmd/safe`` → Twist/TwistStamped on ``cmd_vel`` (zero commands when it stops);
     ``map/esdf`` → OccupancyGrid with Nav2's costmap values; ``safety/status`` →
     DiagnosticArray; optionally TF (``odom → base_link``, ``map → odom``) from ``state``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Annotated, ClassVar

import zenoh
import zenoh.ext as zenoh_ext
from pydantic import Field, model_validator

from riskfield.protocol import EsdfGrid, RobotState, SafetyStatus, VelocityCommand

from ..runtime.arbiter import CommandMux, MuxInput
from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .messages import (
    CameraInfo,
    CdrError,
    Distro,
    FrameMismatch,
    Odometry,
    RosCodec,
    Transform,
    TwistType,
    costmap,
    decode_camera_info,
    decode_compressed_image,
    decode_image,
    diagnostic_level,
    odometry_to_state,
    state_to_tf,
)

CDR_ENCODING = "application/cdr"
Priority = Annotated[int, Field(ge=0, le=255)]  # twist_mux clamps priorities to [0, 255]
Seconds = Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)]
Metres = Annotated[float, Field(ge=0, le=100, allow_inf_nan=False)]


class Ros2BridgeSettings(NodeSettings):
    """Topic names are ROS names relative to the bridge's namespace; "" switches a topic off."""

    SERVICE: ClassVar[str] = "ros2-bridge"

    namespace: str = Field(default="", description="zenoh-bridge-ros2dds `namespace`, e.g. limo1")
    ros_distro: Distro = "jazzy"
    """ROS 2 distribution whose message definitions encode and decode the CDR samples."""
    # Velocity inputs → cmd/ref (twist_mux-style arbitration).
    cmd_in_topic: str = "cmd_vel_smoothed"
    """Velocity input arbitrated into cmd/ref (Nav2's smoothed output); empty: off."""
    cmd_in_type: TwistType = "Twist"
    """Message type of cmd_in_topic: Twist or TwistStamped."""
    cmd_in_priority: Priority = 10
    """twist_mux priority of cmd_in_topic: the highest live input wins."""
    cmd_in_timeout_s: Seconds = 0.5
    """cmd_in_topic stops counting as live this long after its last message."""
    teleop_topic: str = ""
    """Optional teleop velocity input; empty: off."""
    teleop_type: TwistType = "Twist"
    """Message type of teleop_topic: Twist or TwistStamped."""
    teleop_priority: Priority = 100
    """twist_mux priority of teleop_topic (above Nav2 by default)."""
    teleop_timeout_s: Seconds = 0.5
    """teleop_topic stops counting as live this long after its last message."""
    # The safe command out.
    cmd_vel_topic: str = "cmd_vel"
    """Where cmd/safe goes out to the base; empty: off."""
    cmd_out_type: TwistType = "Twist"
    """Message type of cmd_vel_topic: Twist or TwistStamped."""
    watchdog_s: float = Field(default=0.2, gt=0, le=10)
    """No cmd/safe for this long: zero commands go out on cmd_vel_topic."""
    zero_rate_hz: float = Field(default=10.0, gt=0, le=1000)
    """Rate of those zero commands while cmd/safe is silent."""
    # State in: odometry (+ TF map → odom) into the ESDF's frame.
    odom_topic: str = "odom"
    """Odometry read as the robot's state (moved into the ESDF's frame by TF); empty: off."""
    tf_topic: str = "tf"
    """Dynamic TF read for map -> odom; empty: off."""
    tf_static_topic: str = "tf_static"
    """Static TF (TRANSIENT_LOCAL, its history is fetched on joining); empty: off."""
    tf_timeout_s: float = Field(default=1.0, gt=0, le=60, description="age limit of a dynamic map → odom")
    map_frame: str = Field(default="map", description="the ESDF's frame until the first ESDF names it")
    odom_frame: str = "odom"
    """Frame of the odometry, the parent of base_frame."""
    base_frame: str = "base_link"
    """The robot's body frame: the odometry's child frame."""
    # Outputs for RViz / Nav2.
    costmap_topic: str = "riskfield/costmap"
    """OccupancyGrid with Nav2's cost values made from map/esdf; empty: off."""
    inscribed_radius: Metres = 0.1
    """Distance (m) at and below which a cell is inscribed (Nav2's 253), as Nav2's inflation layer."""
    inflation_radius: Metres = 0.55
    """Cells farther than this (m) from any obstacle are free space."""
    cost_scaling_factor: dict[str, Annotated[float, Field(gt=0, le=1000)]] = Field(
        default_factory=lambda: {"high": 3.0, "mid": 5.0, "low": 10.0},
        description="Nav2 cost_scaling_factor per risk group: a smaller factor keeps cost high farther out")
    default_cost_scaling_factor: float = Field(default=10.0, gt=0, le=1000)
    """cost_scaling_factor of a risk group not in cost_scaling_factor."""
    diagnostics_topic: str = "diagnostics"
    """DiagnosticArray made from safety/status; empty: off."""
    diagnostics_rate_hz: float = Field(default=2.0, gt=0, le=100)
    """Most diagnostics per second while the level stays the same (a change goes out at once)."""
    publish_tf: bool = Field(default=False, description="TF from riskfield's state (a simulated robot)")
    max_cdr_bytes: int = Field(default=1 << 20, gt=0, description="larger ROS samples are rejected unparsed")
    # Camera in: a ROS camera driver's images → camera/image (perception).
    image_topic: str = Field(default="", description=(
        "sensor_msgs/Image (8-bit rgb, bgr, rgba, bgra, mono) republished as camera/image rgb8; empty: off"))
    compressed_image_topic: str = Field(default="", description=(
        "sensor_msgs/CompressedImage (JPEG, e.g. image_raw/compressed) republished as camera/image jpeg; empty: off"))
    camera_info_topic: str = Field(default="", description=(
        "sensor_msgs/CameraInfo of those images: their pinhole intrinsics go out in Image.intrinsics; empty: off"))
    camera_info_rectified: bool = Field(default=False, description=(
        "the image topics carry rectified images (image_proc's image_rect): intrinsics from P; false: raw "
        "images, intrinsics from K only when the camera has no distortion"))
    max_image_bytes: int = Field(default=64 << 20, gt=0, description="larger image samples are rejected unparsed")

    @model_validator(mode="after")
    def _consistent(self) -> Ros2BridgeSettings:
        if self.publish_tf and self.odom_topic:
            raise ValueError("publish_tf echoes riskfield's state as TF; with odom_topic set that state comes from "
                             "the robot's own odometry, whose driver already publishes odom → base_link: "
                             "set odom_topic='' to publish TF")
        inputs = [t for t in (self.cmd_in_topic, self.teleop_topic) if t]
        if len(set(inputs)) != len(inputs):
            raise ValueError("teleop_topic and cmd_in_topic must differ")
        if self.cmd_vel_topic in inputs:
            raise ValueError(f"cmd_vel_topic {self.cmd_vel_topic!r} is also a velocity input: the safe command "
                             "would feed back into cmd/ref")
        if self.inscribed_radius > self.inflation_radius:
            raise ValueError("inscribed_radius must not exceed inflation_radius")
        return self


def ros_key(namespace: str, topic: str) -> str:
    """The Zenoh key zenoh-bridge-ros2dds routes ROS topic ``topic`` to under ``namespace``."""
    return "/".join(p.strip("/") for p in (namespace, topic) if p.strip("/"))


class Ros2Bridge:
    """Core of the bridge (no I/O): arbitration, frames, watchdog; bytes in, bytes/messages out."""

    def __init__(self, s: Ros2BridgeSettings):
        self.s = s
        self.codec = RosCodec(s.ros_distro)
        inputs = [MuxInput("nav", s.cmd_in_priority, s.cmd_in_timeout_s)] if s.cmd_in_topic else []
        if s.teleop_topic:
            inputs.append(MuxInput("teleop", s.teleop_priority, s.teleop_timeout_s))
        self.mux = CommandMux(inputs)  # twist_mux's rules (runtime.arbiter), no locks
        self.last_cmd = -float("inf")
        self.map_frame = s.map_frame
        self.static_tf: dict[tuple[str, str], Transform] = {}
        self.dynamic_tf: dict[tuple[str, str], tuple[Transform, float]] = {}

    # -- velocity -------------------------------------------------------------------------------
    def on_velocity(self, name: str, kind: TwistType, raw: bytes, now: float, stamp_ns: int) -> VelocityCommand | None:
        """The ``cmd/ref`` for a velocity sample, or None when a higher-priority input holds the
        robot. Raises ``CdrError`` for bad CDR, ``FrameMismatch`` for a TwistStamped not in the body frame."""
        self._check_size(raw)
        lin, ang, frame = self.codec.decode_twist(raw, kind)
        if frame and frame != self.s.base_frame:
            raise FrameMismatch(f"TwistStamped in frame {frame!r}, not the body frame {self.s.base_frame!r}")
        if self.mux.admit(name, now) is not None:
            return None
        cmd = VelocityCommand(linear=lin, angular=ang, source=f"ros2/{name}")
        # The ROS stamp may be simulation time; the filter judges freshness by our wall clock.
        cmd.header.stamp_ns = stamp_ns
        cmd.header.frame_id = self.s.base_frame
        return cmd

    def on_safe(self, cmd: VelocityCommand, now: float, stamp_ns: int) -> bytes:
        self.last_cmd = now
        return self.codec.encode_twist(cmd, self.s.cmd_out_type, stamp_ns, self.s.base_frame)

    def on_tick(self, now: float, stamp_ns: int) -> bytes | None:
        if now - self.last_cmd > self.s.watchdog_s:
            return self.codec.encode_twist(VelocityCommand.zero("ros2-bridge watchdog"), self.s.cmd_out_type,
                                           stamp_ns, self.s.base_frame)
        return None

    # -- state ----------------------------------------------------------------------------------
    def _check_size(self, raw: bytes) -> None:
        if len(raw) > self.s.max_cdr_bytes:
            raise CdrError(f"{len(raw)} bytes, over max_cdr_bytes = {self.s.max_cdr_bytes}")

    def on_tf(self, raw: bytes, static: bool, now: float) -> int:
        self._check_size(raw)
        transforms = self.codec.decode_tf(raw)
        for tr in transforms:
            if not 0.5 < sum(c * c for c in tr.rotation) < 2.0:  # far from unit: not a rotation at all
                raise ValueError(f"{tr.parent} → {tr.child}: rotation {tr.rotation} is not a unit quaternion")
        for tr in transforms:
            if static:
                self.static_tf[(tr.parent, tr.child)] = tr
            else:
                self.dynamic_tf[(tr.parent, tr.child)] = (tr, now)
        return len(transforms)

    def transform(self, parent: str, child: str, now: float) -> Transform | None:
        if (parent, child) in self.static_tf:
            return self.static_tf[(parent, child)]
        tr, t = self.dynamic_tf.get((parent, child), (None, 0.0))
        return tr if tr is not None and now - t <= self.s.tf_timeout_s else None

    def on_odometry(self, raw: bytes, now: float) -> RobotState:
        """The map-frame state of an Odometry; ``FrameMismatch`` (reason in the text) when its
        frames do not match the ESDF's frame and the robot's body frame, ``ValueError`` when it
        is malformed."""
        self._check_size(raw)
        o: Odometry = self.codec.decode_odometry(raw)
        if o.child_frame_id and o.child_frame_id != self.s.base_frame:
            raise FrameMismatch(f"odometry child frame {o.child_frame_id!r} is not the body frame "
                                f"{self.s.base_frame!r}")
        tr = None if o.frame_id == self.map_frame else self.transform(self.map_frame, o.frame_id, now)
        return odometry_to_state(o, self.map_frame, tr)

    # -- outputs --------------------------------------------------------------------------------
    def on_esdf(self, esdf: EsdfGrid) -> None:
        self.map_frame = esdf.header.frame_id or self.s.map_frame

    def occupancy_grid(self, esdf: EsdfGrid) -> bytes:
        data = costmap(esdf, self.s.cost_scaling_factor, self.s.default_cost_scaling_factor,
                       self.s.inscribed_radius, self.s.inflation_radius)
        return self.codec.encode_occupancy_grid(esdf, data, esdf.header.stamp_ns)

    def on_state_tf(self, state: RobotState) -> bytes:
        return self.codec.encode_tf(state_to_tf(state, self.s.odom_frame, self.s.base_frame))


def setup(node: Node, s: Ros2BridgeSettings) -> None:
    core = Ros2Bridge(s)
    key = lambda topic: ros_key(s.namespace, topic)  # noqa: E731
    cmd_vel = key(s.cmd_vel_topic)

    def count(name: str) -> None:
        node.stats[name] = node.stats.get(name, 0) + 1

    def reject(what: str, k: str, exc: Exception, counter: str) -> None:
        count(counter)
        node.ratelog(logging.WARNING, counter, f"rejected {what} on {k}: {exc}")

    def foreign(k: str, expected: str) -> bool:
        """A put on a key expression that merely matches ours (a wildcard) is dropped and counted."""
        if k == expected:
            return False
        count("wildcard_dropped")
        node.ratelog(logging.WARNING, "wildcard", f"dropped a sample on {k}: only {expected} is served")
        return True

    def cdr_put(k: str, payload: bytes) -> None:
        node.publish_raw(k, payload, CDR_ENCODING)

    # Velocity inputs → cmd/ref.
    def velocity_handler(name: str, kind: TwistType, expected: str):
        def on_velocity(k: str, payload: bytes) -> None:
            if foreign(k, expected):
                return
            try:
                cmd = core.on_velocity(name, kind, payload, time.monotonic(), time.time_ns())
            except FrameMismatch as exc:
                return reject(f"a {kind}", k, exc, f"{name}_frame_mismatch")
            except ValueError as exc:
                return reject(f"a {kind}", k, exc, f"{name}_invalid")
            if cmd is None:
                count(f"{name}_preempted")
                return
            node.publish(node.keys.cmd_ref_of(cmd.source), cmd)
        return on_velocity

    if s.cmd_in_topic:
        node.subscribe(key(s.cmd_in_topic), None, velocity_handler("nav", s.cmd_in_type, key(s.cmd_in_topic)))
    if s.teleop_topic:
        node.subscribe(key(s.teleop_topic), None, velocity_handler("teleop", s.teleop_type, key(s.teleop_topic)))

    # Safe command out, with the watchdog.
    def on_safe(cmd: VelocityCommand) -> None:
        cdr_put(cmd_vel, core.on_safe(cmd, time.monotonic(), time.time_ns()))

    def tick() -> None:
        zero = core.on_tick(time.monotonic(), time.time_ns())
        if zero is not None:
            cdr_put(cmd_vel, zero)

    node.subscribe(node.keys.cmd_safe, VelocityCommand, on_safe)
    node.every(1.0 / s.zero_rate_hz, tick)

    # State in.
    if s.odom_topic:
        def on_odom(k: str, payload: bytes) -> None:
            if foreign(k, key(s.odom_topic)):
                return
            try:
                state = core.on_odometry(payload, time.monotonic())
            except FrameMismatch as exc:
                return reject("an Odometry", k, exc, "state_frame_mismatch")
            except ValueError as exc:  # bad CDR, NaN/Inf, a zero quaternion
                return reject("an Odometry", k, exc, "odom_invalid")
            node.publish(node.keys.state, state)

        node.subscribe(key(s.odom_topic), None, on_odom)

        def on_tf(k: str, payload: bytes, static: bool) -> None:
            if foreign(k, key(s.tf_static_topic if static else s.tf_topic)):
                return
            try:
                core.on_tf(payload, static, time.monotonic())
            except ValueError as exc:
                reject("a TFMessage", k, exc, "tf_invalid")

        if s.tf_topic:
            # TF carries many frames per topic: every sample matters, not just the latest.
            node.subscribe(key(s.tf_topic), None, lambda k, p: on_tf(k, p, False), queue="fifo", maxlen=1000)
        if s.tf_static_topic:
            # /tf_static is TRANSIENT_LOCAL: zenoh-bridge-ros2dds serves it from an AdvancedPublisher
            # with a cache and publisher detection (route_publisher.rs, RoutePublisher::create), so a
            # late-joining bridge still gets the static transforms through an AdvancedSubscriber's history.
            static_key = key(s.tf_static_topic)

            def on_static(k: str, payload: bytes) -> None:
                count("tf_static_received")  # not a runtime subscription: NodeStatus.received misses it
                on_tf(k, payload, True)

            def on_static_sample(sample: zenoh.Sample) -> None:
                k, payload = str(sample.key_expr), sample.payload.to_bytes()
                node.post(lambda: on_static(k, payload))

            static_sub = zenoh_ext.declare_advanced_subscriber(
                node.session, static_key, on_static_sample,
                history=zenoh_ext.HistoryConfig(detect_late_publishers=True))
            node.on_close(static_sub.undeclare)

    if s.image_topic or s.compressed_image_topic:
        _camera_in(node, s, core.codec, key, foreign, reject, count)

    # Map, status and TF out.
    def on_esdf(esdf: EsdfGrid) -> None:
        core.on_esdf(esdf)  # the ESDF names the frame every state must be in
        if not s.costmap_topic:
            return
        try:
            payload = core.occupancy_grid(esdf)
        except ValueError as exc:
            return reject("an ESDF for the costmap", node.keys.esdf, exc, "costmap_skipped")
        cdr_put(key(s.costmap_topic), payload)

    if s.costmap_topic or s.odom_topic:
        node.subscribe(node.keys.esdf, EsdfGrid, on_esdf)

    if s.diagnostics_topic:
        last = {"t": -float("inf"), "level": -1}

        def on_status(status: SafetyStatus) -> None:
            now, level = time.monotonic(), diagnostic_level(status)[0]
            # /diagnostics is a low-rate topic: throttle, but never hold back a change of level.
            if level == last["level"] and now - last["t"] < 1.0 / s.diagnostics_rate_hz:
                return
            last["t"], last["level"] = now, level
            cdr_put(key(s.diagnostics_topic), core.codec.encode_diagnostics(status, node.keys.root, time.time_ns()))

        node.subscribe(node.keys.safety_status, SafetyStatus, on_status)

    if s.publish_tf and s.tf_topic:
        node.subscribe(node.keys.state, RobotState, lambda st: cdr_put(key(s.tf_topic), core.on_state_tf(st)))


def _camera_in(node: Node, s: Ros2BridgeSettings, codec: RosCodec, key: Callable[[str], str],
               foreign: Callable[[str, str], bool], reject: Callable[..., None], count: Callable[[str], None]) -> None:
    """A ROS camera driver's images (+ camera_info) → ``camera/image``, stamped with the driver's
    stamp when it is on the wall clock (else the arrival, counted in ``image_stamp_fallbacks``)."""
    info: dict[str, CameraInfo | None] = {"last": None}

    def intrinsics(width: int, height: int) -> tuple[float, float, float, float] | None:
        ci = info["last"]
        if ci is None or (ci.width, ci.height) != (width, height):
            return None  # none yet, or of another resolution: perception treats the image as uncalibrated
        return ci.intrinsics(s.camera_info_rectified)

    def handler(kind: str, expected: str) -> Callable[[str, bytes], None]:
        def on_image(k: str, payload: bytes) -> None:
            if foreign(k, expected):
                return
            try:
                if len(payload) > s.max_image_bytes:
                    raise CdrError(f"{len(payload)} bytes, over max_image_bytes = {s.max_image_bytes}")
                decode = decode_image if kind == "Image" else decode_compressed_image
                image, from_ros = decode(codec, payload, time.time_ns())
            except ValueError as exc:  # bad CDR, an unsupported encoding, a size the bytes do not hold
                return reject(f"a {kind}", k, exc, "image_invalid")
            if not from_ros:
                count("image_stamp_fallbacks")
            image.intrinsics = intrinsics(image.width, image.height)
            node.publish(node.keys.camera_image, image)
        return on_image

    if s.image_topic:
        node.subscribe(key(s.image_topic), None, handler("Image", key(s.image_topic)))
    if s.compressed_image_topic:
        node.subscribe(key(s.compressed_image_topic), None,
                       handler("CompressedImage", key(s.compressed_image_topic)))
    if s.camera_info_topic:
        def on_info(k: str, payload: bytes) -> None:
            if foreign(k, key(s.camera_info_topic)):
                return
            try:
                ci = decode_camera_info(codec, payload)
            except ValueError as exc:
                return reject("a CameraInfo", k, exc, "camera_info_invalid")
            if ci.intrinsics(s.camera_info_rectified) is None and any(c != 0 for c in ci.d):
                node.ratelog(logging.WARNING, "camera_info_distorted",
                             f"{k}: the camera has distortion and camera_info_rectified is false: images go out "
                             "without intrinsics (subscribe to a rectified topic, image_proc's image_rect)")
            info["last"] = ci

        node.subscribe(key(s.camera_info_topic), None, on_info)


SERVICE = ServiceSpec("ros2-bridge", Ros2BridgeSettings, setup)
