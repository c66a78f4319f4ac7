"""The camera node: a V4L2 camera, a video file or an image folder → ``camera/image``.

* **Sources** — ``source`` is a V4L2 device (``/dev/videoN``: ``input_format`` MJPEG or YUYV,
  ``width`` × ``height``, ``rate_hz``), any file FFmpeg reads, or a folder of images (natural
  order, ``rate_hz``, default 10). A recording plays in real time (``pace=realtime``: at its own
  timing, or at ``rate_hz``) or as fast as perception takes it (``pace=perception``: the next frame
  goes out when a ``perception/frame`` with the last image's stamp arrives, or after
  ``ack_timeout_s``); ``loop`` starts it over at the end. Library: PyAV (``capture.py`` says why).
* **Stamps** — ``header.stamp_ns`` is the capture time: a V4L2 buffer's driver timestamp moved to
  the wall clock (the arrival time, counted in ``stamp_fallbacks``, when a driver gives none); a
  recording's container time after the start of playback (``pace=realtime``), or the release time
  (``pace=perception``, where container times would run ahead of or behind the wall clock). Stamps
  strictly increase, across loops too.
* **Latest frame only** — the capture thread overwrites one slot and the publisher takes the
  newest (``latest.LatestSlot``); frames overwritten before publication are ``frames_dropped`` in
  ``status/camera``. Only frames that are published are decoded.
* **Calibration** — ``calibration`` is a ROS camera_info or OpenCV FileStorage YAML file
  (``calibration.py``). Images are **undistorted here** (``undistort.py``, the why is there) and carry
  the pinhole intrinsics of their pixels in ``Image.intrinsics`` (fx, fy, cx, cy; the calibration's
  ``P``, scaled when the camera runs at another resolution of the same aspect ratio). With
  ``undistort=false`` a distorted camera's images carry no intrinsics: perception then treats them
  as uncalibrated rather than as pinhole images they are not.
* **Encoding** — ``encoding=jpeg`` (default; ~20× smaller on the link to the perception host)
  sends a camera's MJPEG frame as it is when no pixel has to change (no undistortion, and the frame
  carries its Huffman tables, ``riskfield.protocol.jpeg``), and encodes (``jpeg_quality``) otherwise;
  ``encoding=rgb8`` sends the uint8 H×W×3 array, like the simulator.

Bad frames (undecodable, a size the calibration does not fit) are counted (``frames_rejected``) and
logged at a limited rate; a V4L2 device that fails is reopened every ``reopen_s``; the node keeps
serving. The end of a recording without ``loop`` is logged once (``eof`` = 1); the node stays up.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar, Literal

import av.error
from pydantic import Field, model_validator
from pydantic_settings import SettingsConfigDict

from riskfield.protocol import Image, PerceptionFrame
from riskfield.protocol.jpeg import jpeg_info
from riskfield.protocol.messages import Header

from ..runtime.node import Node
from ..runtime.service import ServiceSpec, ServiceUnavailable
from ..runtime.settings import NodeSettings
from .calibration import Calibration, load_calibration
from .capture import (
    Captured,
    CaptureThread,
    FileSource,
    FolderSource,
    Pixels,
    Source,
    SourceError,
    V4l2Source,
    source_kind,
)
from .latest import LatestSlot
from .undistort import Undistorter


class CameraSettings(NodeSettings):
    model_config = SettingsConfigDict(populate_by_name=True)
    SERVICE: ClassVar[str] = "camera"

    source: str = Field("/dev/video0", validation_alias="riskfield_camera_source", description=(
        "V4L2 device (/dev/videoN), a video file FFmpeg reads, or a folder of images (env RISKFIELD_CAMERA_SOURCE)"))
    input_format: Literal["mjpeg", "yuyv"] = Field("mjpeg", description="V4L2: pixel format asked of the device")
    width: int | None = Field(None, gt=0, le=16384, description="V4L2: capture width (None: the device's mode)")
    height: int | None = Field(None, gt=0, le=16384, description="V4L2: capture height (None: the device's mode)")
    rate_hz: float | None = Field(None, gt=0, le=1000, description=(
        "V4L2: frame rate asked of the driver; video file: play at this rate instead of its own timing; "
        "image folder: frames per second (None: 10)"))
    pace: Literal["realtime", "perception"] = Field("realtime", description=(
        "recordings: realtime (their own timing) or perception (the next frame when perception has "
        "answered the last one, see ack_timeout_s); a live camera is always realtime"))
    ack_timeout_s: float = Field(2.0, gt=0, description=(
        "pace=perception: send the next frame anyway after this long without a perception/frame "
        "stamped like the last image (a backend that skips frames)"))
    loop: bool = Field(False, description="recordings: start over at the end (stamps keep increasing)")
    calibration: Path | None = Field(None, description="ROS camera_info or OpenCV FileStorage YAML file")
    undistort: bool = Field(True, description=(
        "resample a distorted camera's images onto the calibration's pinhole model (P); false: send them "
        "as captured, without intrinsics"))
    encoding: Literal["jpeg", "rgb8"] = Field("jpeg", description="Image encoding on the wire")
    jpeg_quality: int = Field(90, ge=1, le=100, description="JPEG quality of frames the node encodes")
    camera_frame: str = Field("camera", description="header.frame_id of the images")
    reopen_s: float = Field(1.0, gt=0, description="V4L2: wait between attempts to reopen a device that failed")
    wait_subscriber: bool = Field(True, description=(
        "recordings: start playing once something subscribes to camera/image (perception, a recorder), "
        "so its first frames are not played to no one"))

    @model_validator(mode="after")
    def _live_is_realtime(self) -> CameraSettings:
        if self.pace == "perception" and source_kind(self.source) == "v4l2":
            raise ValueError(f"pace=perception needs a recording; {self.source} is a live camera (pace=realtime)")
        if (self.width is None) != (self.height is None):
            raise ValueError("give both width and height, or neither")
        return self


def open_source(s: CameraSettings, on_error: Callable[[str], None] = lambda _m: None) -> Source:
    """The source the settings name, opened: a missing file or device fails here, at start."""
    kind = source_kind(s.source)
    source: Source
    if kind == "v4l2":
        source = V4l2Source(s.source, s.input_format, s.width, s.height, s.rate_hz)
    else:
        if not Path(s.source).exists():
            raise FileNotFoundError(f"camera source {s.source} does not exist")
        source = FolderSource(s.source, s.rate_hz or 10.0) if kind == "folder" else FileSource(s.source, on_error)
    source.open()
    return source


class Camera:
    """The publisher side: takes the newest captured frame, makes it an ``Image``, publishes it."""

    def __init__(self, node: Node, s: CameraSettings, source: Source, calib: Calibration | None):
        self.node, self.s, self.source, self.calib = node, s, source, calib
        self.slot: LatestSlot[Captured] = LatestSlot()
        self.pixels = Pixels(s.jpeg_quality)
        self._calibs: dict[tuple[int, int], tuple[Calibration, Undistorter | None]] = {}
        self.published = self.rejected = self.reencoded = self.ack_timeouts = 0
        self.awaiting: int | None = None  # pace=perception: stamp of the image waiting for its frame
        self._sent = 0.0
        period = int(1e9 / s.rate_hz) if s.rate_hz and not source.live else None
        self.capture = CaptureThread(source, self.slot, lambda: node.post(self.on_frame),
                                     lambda msg: node.post(lambda: self._capture_error(msg)),
                                     lambda: node.post(self._eof), pace=s.pace, loop=s.loop, period_ns=period,
                                     reopen_s=s.reopen_s)
        self.intrinsics_on_wire = calib is not None and (s.undistort or not calib.distorted)
        self._started = False
        self._probe: Any = None

    # -- capture thread → loop thread ---------------------------------------------------------
    def _capture_error(self, msg: str) -> None:
        self.node.ratelog(logging.WARNING, "capture", f"{msg}")

    def _eof(self) -> None:
        self.node.log.info("end of %s after %d frames (loop=false); staying up", self.s.source,
                           self.capture.stats.captured)

    def on_frame(self) -> None:
        item = self.slot.take()
        if item is None:
            return
        t0 = time.perf_counter()
        try:
            image = self.image(item)
        except (ValueError, av.error.FFmpegError) as exc:
            self.rejected += 1
            self.node.ratelog(logging.WARNING, "reject", f"could not make an image of frame {item.index}: "
                              f"{exc}")
            self.capture.want.set()  # pace=perception: nothing to wait for
            return
        self.node.stats["convert_ms"] = (time.perf_counter() - t0) * 1e3
        self.node.publish(self.node.keys.camera_image, image)
        self.published += 1
        self.node.stats["capture_to_publish_ms"] = (time.time_ns() - item.stamp_ns) / 1e6
        if self.s.pace == "perception":
            self.awaiting, self._sent = image.header.stamp_ns, time.monotonic()

    def on_perception(self, frame: PerceptionFrame) -> None:
        if self.awaiting is not None and frame.header.stamp_ns == self.awaiting:
            self.awaiting = None
            self.capture.want.set()

    def check_ack(self) -> None:
        if self.awaiting is not None and time.monotonic() - self._sent > self.s.ack_timeout_s:
            self.awaiting = None
            self.ack_timeouts += 1
            self.capture.want.set()

    # -- frame → Image ------------------------------------------------------------------------------
    def _calibration(self, width: int, height: int) -> tuple[Calibration, Undistorter | None] | None:
        if self.calib is None:
            return None
        got = self._calibs.get((width, height))
        if got is None:
            calib = self.calib.scaled(width, height)  # CalibrationError (a ValueError): rejected
            undistorter = Undistorter(calib) if self.s.undistort and calib.distorted else None
            got = self._calibs[(width, height)] = (calib, undistorter)
        return got

    def image(self, item: Captured) -> Image:
        raw = item.raw
        cal = self._calibration(raw.width, raw.height)
        undistorter = cal[1] if cal is not None else None
        intrinsics = cal[0].intrinsics if cal is not None and self.intrinsics_on_wire else None
        header = Header(stamp_ns=item.stamp_ns, frame_id=self.s.camera_frame)
        if raw.kind == "jpeg" and self.s.encoding == "jpeg" and undistorter is None:
            info = jpeg_info(raw.data)
            if (info.width, info.height) != (raw.width, raw.height):
                raise ValueError(f"JPEG is {info.width}x{info.height}, the stream {raw.width}x{raw.height}")
            if info.has_huffman_tables:  # as captured: no decode, no re-encode
                return Image(header=header, encoding="jpeg", width=info.width, height=info.height, data=raw.data,
                             intrinsics=intrinsics)
            self.reencoded += 1
        rgb = self.pixels.rgb(raw)
        if undistorter is not None:
            rgb = undistorter(rgb)
        h, w = rgb.shape[:2]
        data = rgb if self.s.encoding == "rgb8" else self.pixels.jpeg(rgb)
        return Image(header=header, encoding=self.s.encoding, width=w, height=h, data=data, intrinsics=intrinsics)

    def update_stats(self) -> None:
        st = self.capture.stats
        self.node.stats.update(frames_captured=st.captured, frames_dropped=self.slot.dropped,
                               frames_published=self.published, frames_rejected=self.rejected,
                               capture_errors=st.errors, stamp_fallbacks=st.stamp_fallbacks, loops=st.loops,
                               reopens=st.reopens, eof=float(st.eof), jpeg_reencoded=self.reencoded,
                               ack_timeouts=self.ack_timeouts)

    def start_when_heard(self) -> None:
        """Timer: start the recording once a subscriber matches ``camera/image``."""
        if self._started:
            return
        if self._probe is None:
            self._probe = self.node.session.declare_publisher(self.node.keys.camera_image)
        if self._probe.matching_status.matching:
            self._probe.undeclare()
            self._probe = None
            self.start()

    def start(self) -> None:
        if not self._started:
            self._started = True
            self.capture.start()

    def close(self) -> None:
        if self._probe is not None:
            self._probe.undeclare()
            self._probe = None
        self.capture.stop()
        self.source.close()


def setup(node: Node, s: CameraSettings) -> Camera:
    calib = load_calibration(s.calibration) if s.calibration is not None else None
    try:
        source = open_source(s, lambda msg: node.post(lambda: node.ratelog(logging.WARNING, "decode", msg)))
    except SourceError as exc:
        raise ServiceUnavailable(str(exc)) from exc
    cam = Camera(node, s, source, calib)
    if calib is not None and calib.distorted and not s.undistort:
        node.log.warning("undistort=false with a distorted calibration: images go out without intrinsics")
    if s.pace == "perception":
        node.subscribe(node.keys.perception_frame, PerceptionFrame, cam.on_perception, queue="latest")
        node.every(min(0.1, s.ack_timeout_s / 4), cam.check_ack)
    node.every(min(0.25, s.status_period_s / 2), cam.update_stats)
    node.on_close(cam.capture.stop)
    cam.update_stats()
    if source.live or not s.wait_subscriber:
        node.post(cam.start)  # once the node serves
    else:
        node.every(0.05, cam.start_when_heard)
    node.log.info("%s (%s), pace %s, %s on the wire%s", s.source, source_kind(s.source), s.pace, s.encoding,
                  f", calibrated ({calib.model}, undistort={s.undistort})" if calib else ", uncalibrated")
    return cam


SERVICE = ServiceSpec("camera", CameraSettings, setup)


