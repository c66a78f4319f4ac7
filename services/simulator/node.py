"""The simulator node: consumes ``cmd/safe``, publishes ``state`` and ``camera/image``.

Simulation-only keys (additive; nothing outside simulation depends on them):

* ``{prefix}/{robot}/sim/truth`` — ``PerceptionFrame/1`` with the perfect camera-frame
  pointmap as depth + intrinsics at every ``truth_stride``-th pixel, the true ``T_WC``,
  confidence ``CERTAIN_CONFIDENCE`` (0 where a ray hit nothing) and ground-truth ADE20K labels,
  published right after each image **with the same header stamp**, so the perception
  ``sim`` backend pairs image and truth by ``stamp_ns`` across processes.
* ``{prefix}/{robot}/camera/depth`` — with ``publish_depth``: ``DepthImage/1`` (additive), the
  rendered depth (z, metres; 0 where nothing was hit) and the camera's intrinsics, stamped like
  the image: what an RGB-D camera gives the perception ``rgbd`` backend.
* ``{prefix}/{robot}/sim/actors`` — with ``publish_actors``: ``SimActors/1``, the ground-truth
  position and velocity of every present object that moves (walkers), computed by the ``World`` at
  the instant the camera image shows and published with **the image's stamp** (with the state
  instead when the camera is off), so a benchmark compares a map built from that image with the
  truth it showed.
* ``{prefix}/{robot}/sim/reset`` — start over: a new ``World`` (time 0, the robot at its start, the
  objects as the scenario lists them) from an empty payload (the same scenario), a scenario name or
  path (UTF-8), or a scenario map (msgpack or JSON). Benchmarks run many scenarios on one simulator
  process this way instead of paying its start-up each time. The robot's jump back to its start
  is announced on ``{prefix}/{robot}/state/relocalise`` (the new state) before the next ``state``.
* ``{prefix}/{robot}/sim/spawn`` — add an object while running (the unseen obstacle): a msgpack
  or JSON map in the scenario file's object format, e.g. ``{"class": "box", "position": [1, 0]}``.

Time: the world advances by the wall-clock time elapsed since the previous physics tick (in
``physics_hz`` sub-steps), so it runs in real time whatever the timer jitter; a stall longer
than ``max_step_s`` is not caught up (simulated time then lags wall time, reported in status).
"""

from __future__ import annotations

import io
import json
import logging
import time
from typing import ClassVar, Literal

import msgpack
import numpy as np
from pydantic import Field, ValidationError

from riskfield.protocol import (
    CERTAIN_CONFIDENCE,
    DepthImage,
    Image,
    PerceptionFrame,
    RobotState,
    SimActors,
    VelocityCommand,
)
from riskfield.protocol.messages import Header

from ..geometry.camera import PinholeCamera
from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .camera import Render
from .robots import ROBOT_TYPES
from .scenario import ObjectSpec, load_scenario
from .world import World


class SimulatorSettings(NodeSettings):
    SERVICE: ClassVar[str] = "simulator"

    scenario: str = Field("navigation", description="built-in name, random:SEED, or a scenario YAML path")
    robot_type: str | None = Field(None, description=f"override the scenario's robot: {', '.join(ROBOT_TYPES)}")
    physics_hz: float = Field(200.0, gt=0, le=5000)
    """Physics sub-step rate of the simulated world."""
    state_hz: float = Field(50.0, gt=0, le=1000)
    """Rate of the robot's state."""
    camera_hz: float = Field(10.0, ge=0, le=120, description="0 disables the camera")
    watchdog_s: float = Field(0.2, gt=0)
    """A command older than this is replaced by zero (the robot brakes), like the LIMO bridge's watchdog."""
    publish_truth: bool = True
    """Publish the camera's ground-truth frame on sim/truth (what perception's sim geometry needs)."""
    truth_stride: int = Field(2, ge=1, le=16)
    """sim/truth carries every n-th pixel of the image in each direction, as depth (float32) and
    intrinsics: the size perception's sim geometry and the mapping work at (the mapping's
    ``pixel_stride``); 1: every pixel."""
    image_encoding: Literal["rgb8", "jpeg"] = Field(
        "jpeg", description="camera/image as JPEG (what crosses a robot's Wi-Fi: ~13 KB a frame here against "
        "590 KB of rgb8) or raw rgb8")
    jpeg_quality: int = Field(90, ge=1, le=100, description="JPEG quality of camera/image (Pillow's scale)")
    publish_depth: bool = Field(False, description="also publish camera/depth (RGB-D robots, perception rgbd)")
    publish_actors: bool = Field(True, description="publish sim/actors: ground truth of the moving objects")
    max_step_s: float = Field(0.25, gt=0)
    """A stall longer than this is not caught up: simulated time then lags wall time (reported in status)."""
    map_frame: str = "map"
    """frame_id of the state, the ground truth and the actors."""
    camera_frame: str = "camera"
    """frame_id of the camera images and depth."""


def jpeg_bytes(rgb: np.ndarray, quality: int) -> bytes:
    """The JPEG file of an HxWx3 uint8 image. Compressed here, at the source, like a camera node
    does: the image then crosses every hop (the router, a robot's Wi-Fi) at its compressed size,
    and perception decodes it once (``perception.node.decode_image``)."""
    from PIL import Image as PILImage  # the `sim` extra

    out = io.BytesIO()
    PILImage.fromarray(rgb).save(out, format="JPEG", quality=quality)
    return out.getvalue()


def truth_frame(render: Render, camera: PinholeCamera, stride: int, header: Header, seq: int) -> PerceptionFrame:
    """The ``sim/truth`` of one render: every ``stride``-th pixel (0, n, 2n, …) as float32 depth with
    the strided camera's intrinsics, ``CERTAIN_CONFIDENCE`` where a ray hit (0 elsewhere: the truth is
    certain, not MASt3R's least certain pixel), the true labels."""
    depth = np.ascontiguousarray(render.depth[::stride, ::stride], np.float32)
    return PerceptionFrame(header=header, T_WC=render.T_WC, depth=depth, intrinsics=camera.strided(stride).intrinsics,
                           confidence=np.where(depth > 0, np.float32(CERTAIN_CONFIDENCE), np.float32(0.0)),
                           labels=np.ascontiguousarray(render.labels[::stride, ::stride]), keyframe_id=seq)


class Simulator:
    """Glue between the node and the pure ``World``: wall time → simulated time, messages."""

    def __init__(self, node: Node, s: SimulatorSettings):
        self.node, self.s = node, s
        self.world = self._world(s.scenario)
        self._last = time.monotonic()
        self._t0 = self._last
        self.frames = 0
        self.spawn_invalid = 0
        self.resets = 0
        self.reset_invalid = 0
        scenario = self.world.scenario
        if s.camera_hz > 0:
            self.world.render()  # compiles the renderer's kernel before the first camera frame
        node.log.info("scenario %s: %d objects, robot %s, camera %dx%d", scenario.name,
                      len(self.world.scene.objects), scenario.robot.type, self.world.camera.width,
                      self.world.camera.height)

    def _world(self, source: str | dict) -> World:
        scenario = load_scenario(source)
        if self.s.robot_type is not None:
            robot = scenario.robot.model_copy(update={"type": self.s.robot_type})
            scenario = scenario.model_copy(update={"robot": robot})
            load_scenario(scenario.model_dump(by_alias=True))  # validates the override
        return World(scenario, physics_dt=1.0 / self.s.physics_hz, watchdog_s=self.s.watchdog_s)

    def on_reset(self, key: str, payload: bytes) -> None:
        try:
            source: str | dict = self.s.scenario
            if payload:
                try:
                    data = msgpack.unpackb(payload, raw=False)
                except Exception:
                    text = payload.decode("utf-8")
                    data = json.loads(text) if text.lstrip().startswith("{") else text
                if not isinstance(data, (dict, str)):
                    raise ValueError("the payload must be a scenario map or a scenario name/path")
                source = data
            world = self._world(source)
        except (ValueError, ValidationError, UnicodeDecodeError, KeyError, OSError) as exc:
            self.reset_invalid += 1
            self.node.stats["reset_invalid"] = self.reset_invalid
            self.node.ratelog(logging.WARNING, "invalid:reset", f"rejected a reset request on {key}: {exc}")
            return
        self.world = world
        self._last = self._t0 = time.monotonic()
        self.resets += 1
        self.node.stats["resets"] = self.resets
        self.node.log.info("reset to scenario %s", world.scenario.name)
        # The robot is back at its start: an announced jump, or the filter and the mapping refuse
        # the states that follow as moving faster than the robot can (runtime.continuity).
        self.publish_state(self.node.keys.state_relocalise)

    def tick(self) -> None:
        now = time.monotonic()
        self.world.advance(min(now - self._last, self.s.max_step_s))
        self._last = now
        self.node.stats["sim_time_s"] = self.world.t
        self.node.stats["sim_lag_s"] = (now - self._t0) - self.world.t
        self.node.stats["watchdog_trips"] = self.world.watchdog_trips

    def on_command(self, msg: VelocityCommand) -> None:
        self.tick()  # the command takes effect from now, not from the last physics tick
        self.world.command(np.asarray(msg.linear), np.asarray(msg.angular))

    def on_spawn(self, key: str, payload: bytes) -> None:
        try:
            try:
                data = msgpack.unpackb(payload, raw=False)
            except Exception:
                data = json.loads(payload.decode("utf-8"))
            if not isinstance(data, dict):
                raise ValueError("the payload must be a map")
            name = self.world.add_object(ObjectSpec.model_validate(data))
        except (ValueError, ValidationError, UnicodeDecodeError, KeyError, OSError) as exc:
            self.spawn_invalid += 1
            self.node.stats["spawn_invalid"] = self.spawn_invalid
            self.node.ratelog(logging.WARNING, "invalid:spawn", f"rejected a spawn request on {key}: {exc}")
            return
        self.node.log.info("spawned %s at t = %.2f s", name, self.world.t)

    def publish_state(self, key: str | None = None) -> None:
        self.tick()
        st = self.world.state()
        if self.s.publish_actors and self.s.camera_hz == 0 and key is None:
            self.publish_actors(time.time_ns())
        self.node.publish(key or self.node.keys.state, RobotState(
            header=Header(frame_id=self.s.map_frame), position=tuple(st.position), orientation=tuple(st.orientation),
            linear_velocity=tuple(st.linear_velocity), angular_velocity=tuple(st.angular_velocity)))

    def publish_camera(self) -> None:
        self.tick()
        # The stamp is the time of the world the image shows (DESIGN "What a stamp means": the time
        # of the sensor data), taken before rendering: stamped after it, the ESDF's content age
        # at the filter would leave out the render time (~20 ms here) and look fresher than it is.
        stamp = time.time_ns()
        t0 = time.perf_counter()
        frame = self.world.render()
        self.node.stats["render_ms"] = (time.perf_counter() - t0) * 1e3
        cam = self.world.camera
        data = frame.rgb if self.s.image_encoding == "rgb8" else jpeg_bytes(frame.rgb, self.s.jpeg_quality)
        self.node.publish(self.node.keys.camera_image, Image(
            header=Header(stamp_ns=stamp, frame_id=self.s.camera_frame), encoding=self.s.image_encoding,
            width=cam.width, height=cam.height, data=data))
        if self.s.publish_depth:
            self.node.publish(self.node.keys.camera_depth, DepthImage(
                header=Header(stamp_ns=stamp, frame_id=self.s.camera_frame), depth=frame.depth, fx=cam.fx, fy=cam.fy,
                cx=cam.cx, cy=cam.cy))
        if self.s.publish_truth:
            self.node.publish(self.node.keys.sim_truth, truth_frame(frame, cam, self.s.truth_stride, Header(
                stamp_ns=stamp, frame_id=self.s.map_frame), self.frames))
        if self.s.publish_actors:
            self.publish_actors(stamp)
        self.frames += 1
        p = self.world.state().position
        self.node.stats["gt_clearance_m"] = float(self.world.clearance(np.array([[p[0], p[1], p[2] + 0.1]]))[0])

    def publish_actors(self, stamp: int) -> None:
        """The moving objects as the world holds them now (no tick: the instant ``stamp`` names)."""
        self.node.publish(self.node.keys.sim_actors, SimActors(
            header=Header(stamp_ns=stamp, frame_id=self.s.map_frame), actors=self.world.actors()))


def setup(node: Node, s: SimulatorSettings) -> Simulator:
    sim = Simulator(node, s)
    node.subscribe(node.keys.cmd_safe, VelocityCommand, sim.on_command, queue="latest")
    node.subscribe(node.keys.sim_spawn, None, sim.on_spawn, queue="fifo", maxlen=64)
    node.subscribe(node.keys.sim_reset, None, sim.on_reset, queue="fifo", maxlen=4)
    node.every(1.0 / s.physics_hz, sim.tick)
    node.every(1.0 / s.state_hz, sim.publish_state)
    if s.camera_hz > 0:
        node.every(1.0 / s.camera_hz, sim.publish_camera)
    return sim


SERVICE = ServiceSpec("simulator", SimulatorSettings, setup)
