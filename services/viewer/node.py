"""Viewer node: streams the stack to Rerun and saves it (``view.rrd``) for later.

``live = true`` opens the Rerun viewer when a display is present, otherwise serves the web
viewer (``http://localhost:9090``) — handy on a headless robot computer.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import ClassVar

import numpy as np

from riskfield.protocol import EsdfGrid, PerceptionFrame, RobotState, SafetyStatus, VelocityCommand

from ..runtime.node import Node
from ..runtime.service import ServiceSpec
from ..runtime.settings import NodeSettings
from .draw import esdf_slice_rgb, footprint, pointmap_world


class ViewerSettings(NodeSettings):
    SERVICE: ClassVar[str] = "viewer"

    out: Path = Path("out/view")
    live: bool = False
    z_slice: float = 0.1
    robot_radius: float = 0.15
    pointmap_stride: int = 4


class RerunView:
    def __init__(self, node: Node, s: ViewerSettings):
        import rerun as rr

        self.rr, self.s = rr, s
        s.out.mkdir(parents=True, exist_ok=True)
        self.path = s.out / "view.rrd"
        self.stream = rr.RecordingStream("riskfield", recording_id=f"{node.keys.root}")
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
        self.stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def _t(self, stamp_ns: int) -> None:
        self.stream.set_time("time", timestamp=np.datetime64(stamp_ns, "ns"))

    def esdf(self, g: EsdfGrid) -> None:
        rr = self.rr
        self._t(g.header.stamp_ns)
        self.stream.log("esdf/slice", rr.Image(esdf_slice_rgb(g, self.s.z_slice)))
        k = 0 if g.distance.shape[2] == 1 else None
        occ = np.argwhere(g.distance[:, :, k] < 0 if k is not None else g.distance < 0)
        if occ.shape[1] == 2:
            occ = np.column_stack([occ, np.zeros(len(occ), int)])
        centres = np.asarray(g.origin) + occ * g.voxel_size
        self.stream.log("world/esdf_inside", rr.Points3D(centres, radii=g.voxel_size / 2, colors=[200, 40, 40]))

    def frame(self, f: PerceptionFrame) -> None:
        self._t(f.header.stamp_ns)
        pts, cols = pointmap_world(f, self.s.pointmap_stride)
        self.stream.log("world/pointmap", self.rr.Points3D(pts, colors=cols, radii=0.01))

    def state(self, st: RobotState) -> None:
        rr = self.rr
        self._t(st.header.stamp_ns)
        self.stream.log("world/robot", rr.Transform3D(translation=st.position,
                                                      quaternion=rr.Quaternion(xyzw=st.orientation)))
        self.stream.log("world/footprint", rr.LineStrips3D([footprint(st, self.s.robot_radius)]))

    def command(self, which: str, c: VelocityCommand) -> None:
        self._t(c.header.stamp_ns)
        self.stream.log(f"cmd/{which}/v", self.rr.Scalars(c.linear[0]))
        self.stream.log(f"cmd/{which}/omega", self.rr.Scalars(c.angular[2]))

    def status(self, st: SafetyStatus) -> None:
        self._t(st.header.stamp_ns)
        self.stream.log("safety/h", self.rr.Scalars(st.h))
        self.stream.log("safety/intervening", self.rr.Scalars(float(st.intervening)))
        if st.fallback:
            self.stream.log("safety/log", self.rr.TextLog(f"braking: {st.fallback}", level="WARN"))

    def close(self) -> None:
        self.stream.flush()
        self.stream.disconnect()


def setup(node: Node, s: ViewerSettings) -> RerunView:
    view = RerunView(node, s)
    k = node.keys
    node.subscribe(k.esdf, EsdfGrid, view.esdf)
    node.subscribe(k.perception_frame, PerceptionFrame, view.frame)
    node.subscribe(k.state, RobotState, view.state)
    node.subscribe(k.cmd_ref, VelocityCommand, lambda c: view.command("ref", c))
    node.subscribe(k.cmd_safe, VelocityCommand, lambda c: view.command("safe", c))
    node.subscribe(k.safety_status, SafetyStatus, view.status, queue="fifo")
    return view


SERVICE = ServiceSpec("viewer", ViewerSettings, setup)
