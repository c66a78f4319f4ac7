"""Viewer node: streams the stack to Rerun and saves it (``view.rrd``) for later.

``live = true`` opens the Rerun viewer when a display is present, otherwise serves the web
viewer (``http://localhost:9090``) — handy on a headless robot computer.

Entities (all spatial ones under ``world``, Z up):

- ``world/robot``: ``Transform3D`` from ``state``; ``world/robot/footprint`` its outline, a child
  that moves with it;
- ``world/robot/camera``: the camera's pose in the robot frame (``Transform3D``, from the
  pointmap's ``T_WC``), a ``Pinhole`` and the camera ``Image`` at ``world/robot/camera/image``;
- ``world/esdf``: the ESDF slice at ``z_slice`` as a ``GridMap`` of signed distances in metres
  with a colormap; ``world/esdf/inside`` the voxels inside the inflated set, tinted by risk
  group; ``world/esdf/bounds`` the map's extent;
- ``world/pointmap``: ``Points3D`` with ADE20K ``class_ids``, named by an ``AnnotationContext``;
- ``world/objects``: the tracked people and animals (``map/objects``) as ``Points3D`` of their
  radius, tinted by risk group and labelled; ``world/objects/velocity`` their velocities as
  ``Arrows3D`` (the distance covered in one second);
- ``cmd/*`` and ``safety/*`` scalars; ``safety/log`` a ``TextLog`` line when the filter's
  fallback reason changes (not one per status message).

Each run is its own recording (a fresh recording id); the application id is ``riskfield`` and
the robot id is the recording's name and a recording property (``robot``).
Rerun APIs used: https://rerun.io/docs/reference/types/archetypes (grid_map, pinhole,
annotation_context, points3d, boxes3d, text_log, transform3d), recording properties
(https://rerun.io/docs/reference/types/archetypes/recording_properties).
"""

from __future__ import annotations

import os
import time
import uuid
from collections import Counter
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import Field

from riskfield.protocol import (
    EsdfGrid,
    Image,
    PerceptionFrame,
    RobotState,
    SafetyStatus,
    TrackedObjects,
    VelocityCommand,
)
from riskfield.protocol.platforms import LIMO, CameraMount

from ..geometry.camera import T_base_camera
from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .draw import (
    OnChange,
    ade20k_classes,
    camera_in_robot,
    esdf_slice,
    footprint,
    inside_voxels,
    intrinsics_from_pointmap,
    map_bounds,
    pointmap_world,
    robot_pose,
    tracked_objects,
)

APPLICATION_ID = "riskfield"


class ViewerSettings(NodeSettings):
    SERVICE: ClassVar[str] = "viewer"

    out: Path = Field(Path("out/view"), description="folder for view.rrd")
    live: bool = Field(False, description="open the Rerun viewer (web viewer on port 9090 when headless)")
    z_slice: float = Field(0.1, description="height of the ESDF slice drawn as a grid map (m)")
    robot_radius: float = Field(0.15, gt=0, description="radius of the footprint drawn around the robot (m)")
    pointmap_stride: int = Field(4, ge=1, description="draw every n-th pointmap pixel in each direction")
    camera_hfov_deg: float = Field(90.0, gt=1, lt=179,
                                   description="camera field of view until a pointmap gives the intrinsics")
    camera_period_s: float = Field(0.5, ge=0, description="draw at most one camera image per this period (s), "
                                   "JPEG-compressed, so that view.rrd stays small")
    camera_mount: tuple[float, float, float] = Field(
        LIMO.camera.position, description="camera position in the robot frame until a pointmap gives its pose (m)")


class RerunView:
    def __init__(self, node: Node, s: ViewerSettings):
        import rerun as rr

        self.rr, self.s = rr, s
        s.out.mkdir(parents=True, exist_ok=True)
        self.path = s.out / "view.rrd"
        # A fresh recording id per run, so that two runs never merge into one recording
        # (rr.RecordingStream(application_id, recording_id=...), rerun docs "Apps and Recordings").
        self.recording_id = str(uuid.uuid4())
        self.stream = rr.RecordingStream(APPLICATION_ID, recording_id=self.recording_id)
        sinks: list = [rr.FileSink(str(self.path))]
        if s.live:
            if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
                self.stream.spawn(connect=False)
                sinks.append(rr.GrpcSink())
            else:
                sinks.append(rr.GrpcServerSink())
        self.stream.set_sinks(*sinks)
        if s.live and len(sinks) > 1 and isinstance(sinks[-1], rr.GrpcServerSink):
            rr.serve_web_viewer(connect_to="rerun+http://127.0.0.1:9876/proxy", open_browser=False)
            node.log.info("live view: open http://localhost:9090 (Rerun web viewer)")
        robot = node.settings.robot
        self.stream.send_recording_name(f"{robot} {time.strftime('%Y-%m-%d %H:%M:%S')}")
        self.stream.send_property("robot", rr.AnyValues(robot=robot, key_root=node.keys.root))
        self.stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.stream.log("world/pointmap", rr.AnnotationContext(ade20k_classes()), static=True)
        self.stream.log("world/robot/footprint", rr.LineStrips3D([footprint(s.robot_radius)], colors=[40, 120, 230]),
                        static=True)
        mount = T_base_camera(CameraMount(position=s.camera_mount, rpy_deg=LIMO.camera.rpy_deg))
        self.T_RC = mount
        self.T_WR: np.ndarray | None = None
        self.intrinsics: tuple[float, float, float, float, int] | None = None  # fx, fy, cx, cy, width they hold for
        self.image_size: tuple[int, int] | None = None
        self.last_image_ns: int | None = None
        self._camera_pose(mount)
        self.fallback = OnChange()
        self.drawn: Counter[str] = Counter()  # messages drawn, by kind (tests synchronise on it)

    def _t(self, stamp_ns: int) -> None:
        self.stream.set_time("time", timestamp=np.datetime64(stamp_ns, "ns"))

    def _camera_pose(self, T_RC: np.ndarray) -> None:
        self.stream.log("world/robot/camera", self.rr.Transform3D(translation=T_RC[:3, 3], mat3x3=T_RC[:3, :3]))

    def _pinhole(self) -> None:
        if self.image_size is None:
            return
        w, h = self.image_size
        if self.intrinsics is not None:
            fx, fy, cx, cy, w0 = self.intrinsics
            k = w / w0  # the pointmap may be smaller than the image
            fx, fy, cx, cy = fx * k, fy * k, (cx + 0.5) * k - 0.5, (cy + 0.5) * k - 0.5
        else:
            fx = fy = (w / 2) / np.tan(np.radians(self.s.camera_hfov_deg) / 2)
            cx, cy = (w - 1) / 2, (h - 1) / 2
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        self.stream.log("world/robot/camera", self.rr.Pinhole(image_from_camera=K, resolution=[w, h],
                                                              camera_xyz=self.rr.ViewCoordinates.RDF,
                                                              image_plane_distance=0.3))

    def esdf(self, g: EsdfGrid) -> None:
        self.drawn["esdf"] += 1
        rr = self.rr
        self._t(g.header.stamp_ns)
        d, corner = esdf_slice(g, self.s.z_slice)
        ny, nx = d.shape
        self.stream.log("world/esdf", rr.GridMap(
            data=d.tobytes(), format=rr.components.ImageFormat(width=nx, height=ny, color_model="L",
                                                               channel_datatype="F32"),
            cell_size=g.voxel_size, translation=corner, colormap=rr.components.Colormap.Turbo, opacity=0.8))
        lo, size = map_bounds(g)
        self.stream.log("world/esdf/bounds", rr.Boxes3D(mins=[lo], sizes=[size], colors=[[120, 120, 120]]))
        centres, tint = inside_voxels(g)
        self.stream.log("world/esdf/inside", rr.Points3D(centres, radii=g.voxel_size / 2, colors=tint))

    def frame(self, f: PerceptionFrame) -> None:
        self.drawn["frame"] += 1
        self._t(f.header.stamp_ns)
        pts, classes = pointmap_world(f, self.s.pointmap_stride)
        self.stream.log("world/pointmap", self.rr.Points3D(pts, class_ids=classes, radii=0.01))
        if self.T_WR is not None:
            self.T_RC = camera_in_robot(f.T_WC, self.T_WR)
            self._camera_pose(self.T_RC)
        if self.intrinsics is None:
            k = f.intrinsics or intrinsics_from_pointmap(f.pointmap())
            if k is not None:
                self.intrinsics = (*k, f.pixels[1])
                self._pinhole()

    def objects(self, m: TrackedObjects) -> None:
        self.drawn["objects"] += 1
        rr = self.rr
        self._t(m.header.stamp_ns)
        pos, radii, vel, tint, labels = tracked_objects(m)
        self.stream.log("world/objects", rr.Points3D(pos, radii=radii, colors=tint, labels=labels))
        self.stream.log("world/objects/velocity", rr.Arrows3D(origins=pos, vectors=vel, colors=tint))

    def image(self, im: Image) -> None:
        self.drawn["image"] += 1
        rr = self.rr
        self._t(im.header.stamp_ns)
        if self.image_size != (im.width, im.height):
            self.image_size = (im.width, im.height)
            self._pinhole()
        stamp = im.header.stamp_ns
        if self.last_image_ns is not None and 0 <= stamp - self.last_image_ns < self.s.camera_period_s * 1e9:
            return
        self.last_image_ns = stamp
        if im.encoding == "jpeg":
            self.stream.log("world/robot/camera/image", rr.EncodedImage(contents=im.data, media_type="image/jpeg"))
        else:  # raw RGB would be ~0.6 MB a frame in view.rrd; Image.compress encodes it as JPEG
            self.stream.log("world/robot/camera/image", rr.Image(np.asarray(im.data), color_model="RGB").compress(
                jpeg_quality=80))

    def state(self, st: RobotState) -> None:
        self.drawn["state"] += 1
        rr = self.rr
        self._t(st.header.stamp_ns)
        self.T_WR = robot_pose(st)
        self.stream.log("world/robot", rr.Transform3D(translation=st.position,
                                                      quaternion=rr.Quaternion(xyzw=st.orientation)))

    def command(self, which: str, c: VelocityCommand) -> None:
        self.drawn[f"cmd_{which}"] += 1
        self._t(c.header.stamp_ns)
        self.stream.log(f"cmd/{which}/v", self.rr.Scalars(c.linear[0]))
        self.stream.log(f"cmd/{which}/omega", self.rr.Scalars(c.angular[2]))

    def status(self, st: SafetyStatus) -> None:
        self.drawn["status"] += 1
        rr = self.rr
        self._t(st.header.stamp_ns)
        self.stream.log("safety/h", rr.Scalars(st.h))
        self.stream.log("safety/intervening", rr.Scalars(float(st.intervening)))
        if self.fallback(st.fallback):  # one line per change of reason, not one per status message
            if st.fallback:
                self.stream.log("safety/log", rr.TextLog(f"braking: {st.fallback}", level="WARN"))
            else:
                self.stream.log("safety/log", rr.TextLog("filtering normally", level="INFO"))

    def close(self) -> None:
        self.stream.flush()
        self.stream.disconnect()


def setup(node: Node, s: ViewerSettings) -> RerunView:
    view = RerunView(node, s)
    k = node.keys
    node.subscribe(k.esdf, EsdfGrid, view.esdf)
    node.subscribe(k.perception_frame, PerceptionFrame, view.frame)
    node.subscribe(k.objects, TrackedObjects, view.objects)
    node.subscribe(k.camera_image, Image, view.image)
    node.subscribe(k.state, RobotState, view.state)
    node.subscribe(k.cmd_ref_any, VelocityCommand, lambda c: view.command("ref", c))
    node.subscribe(k.cmd_safe, VelocityCommand, lambda c: view.command("safe", c))
    node.subscribe(k.safety_status, SafetyStatus, view.status, queue="fifo")
    return view


SERVICE = ServiceSpec("viewer", ViewerSettings, setup)
