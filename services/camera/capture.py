"""Frame sources (a V4L2 device, a video file, an image folder) and the capture thread.

Everything here goes through PyAV (FFmpeg's libraries, one wheel with its own FFmpeg build), the
camera's one dependency. Why PyAV, of the three candidates in reach on the robot:

* **av (PyAV)** reads all three sources with one API: V4L2 through libavdevice's
  ``video4linux2`` demuxer (MJPEG or YUYV, size, rate, the kernel's buffer timestamps as packet
  pts), any file FFmpeg reads with its container pts, and still images; it hands MJPEG frames over
  as packets, so a JPEG goes on the wire without a decode, and it encodes JPEG (``mjpeg``) for
  the frames it must touch. No numpy beyond what the base install has, no Qt, no BLAS: a
  ~35 MB aarch64/x86-64 wheel.
* **opencv-python-headless** would read the same sources and bring undistortion, but as a
  ~60 MB library whose ``VideoCapture`` hides the V4L2 buffer timestamps and keeps its own frame
  queue (the opposite of latest-frame-only), for one remap the node does in numpy.
* **linuxpy** is a small pure-Python V4L2 binding with timestamps, but it reads neither video
  files nor images and decodes nothing (YUYV and JPEG would need another library anyway).

V4L2 specifics, from FFmpeg's ``libavdevice/v4l2.c``: the demuxer queues up to 256 kernel buffers
(``desired_video_buffers``) and hands out each as a packet whose pts is the buffer's
``timestamp`` in microseconds (``mmap_read_frame``); with ``timestamps=default`` it is the
kernel's clock, CLOCK_MONOTONIC for UVC, which :func:`latest.driver_stamp_to_wall` moves to the
wall clock. The capture thread dequeues every buffer as it arrives (no decode there), so the
kernel queue never backs up; only the newest frame is decoded, by the publisher.
"""

from __future__ import annotations

import os
import re
import stat
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Literal

import av
import av.error
import numpy as np

from riskfield.protocol.jpeg import jpeg_info

from .latest import LatestSlot, PlaybackClock, driver_stamp_to_wall

SourceKind = Literal["v4l2", "file", "folder"]
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".ppm", ".pgm", ".tif", ".tiff", ".webp")
_JPEG_SUFFIXES = (".jpg", ".jpeg")


def source_kind(source: str) -> SourceKind:
    """``v4l2`` for ``/dev/video*`` or any character device, ``folder`` for a directory, else ``file``."""
    if source.startswith("/dev/video"):
        return "v4l2"
    try:
        mode = os.stat(source).st_mode
    except OSError:
        return "file"
    if stat.S_ISCHR(mode):
        return "v4l2"
    return "folder" if stat.S_ISDIR(mode) else "file"


@dataclass
class RawFrame:
    """One frame as the source gives it: an ``av.VideoFrame`` (decoded), the bytes of a JPEG, or
    the bytes of a YUYV (yuyv422) frame; with its media time or its driver timestamp (ns)."""

    kind: Literal["frame", "jpeg", "yuyv"]
    data: Any
    width: int
    height: int
    pts_ns: int | None = None
    driver_ns: int | None = None


@dataclass
class Captured:
    """A frame in the slot: the raw frame, its capture stamp (wall clock, ns) and its index."""

    raw: RawFrame
    stamp_ns: int
    index: int
    stamp_source: Literal["driver", "arrival", "playback", "release"]


class SourceError(RuntimeError):
    """A source that cannot be opened or read: names the source and the reason."""


# -- sources ------------------------------------------------------------------------------------

class V4l2Source:
    live = True

    def __init__(self, device: str, input_format: str, width: int | None, height: int | None,
                 rate_hz: float | None):
        self.device, self.input_format = device, input_format
        self.width, self.height, self.rate_hz = width, height, rate_hz
        self._container: Any = None
        self._packets: Any = None
        self.codec = ""

    def open(self) -> None:
        options = {"input_format": {"mjpeg": "mjpeg", "yuyv": "yuyv422"}[self.input_format],
                   "timestamps": "default"}  # the kernel's stamps as they are; mapped by the thread
        if self.width and self.height:
            options["video_size"] = f"{self.width}x{self.height}"
        if self.rate_hz:
            options["framerate"] = str(Fraction(self.rate_hz).limit_denominator(1001))
        try:
            self._container = av.open(self.device, format="video4linux2", options=options)
        except (av.error.FFmpegError, OSError) as exc:
            raise SourceError(f"cannot open V4L2 device {self.device} ({self.input_format}"
                              f"{', ' + options['video_size'] if 'video_size' in options else ''}): {exc}") from exc
        stream = self._container.streams.video[0]
        self.codec = stream.codec_context.name
        fmt = stream.codec_context.format
        if self.codec not in ("mjpeg", "rawvideo") or (self.codec == "rawvideo" and fmt is not None
                                                         and fmt.name != "yuyv422"):
            name = fmt.name if fmt is not None else "?"
            self.close()
            raise SourceError(f"{self.device} gives {self.codec}/{name}; input_format mjpeg or yuyv is supported")
        self.width, self.height = stream.codec_context.width, stream.codec_context.height
        self._packets = self._container.demux(stream)

    def read(self) -> RawFrame | None:
        for packet in self._packets:
            if packet.size == 0:  # a buffer the driver flagged corrupt (v4l2.c zeroes its size)
                continue
            data = bytes(packet)  # a copy: the kernel buffer goes back to the driver right away
            driver_ns = None if packet.pts is None else int(packet.pts) * 1000
            kind: Literal["jpeg", "yuyv"] = "jpeg" if self.codec == "mjpeg" else "yuyv"
            return RawFrame(kind, data, self.width or 0, self.height or 0, driver_ns=driver_ns)
        raise SourceError(f"{self.device} stopped delivering frames")

    def rewind(self) -> None:  # pragma: no cover - a live source has no beginning
        raise SourceError("a live camera cannot be rewound")

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
            self._container = None


class FileSource:
    """Any file FFmpeg reads; frames in presentation order with their container time."""

    live = False

    def __init__(self, path: str, on_error: Callable[[str], None] | None = None):
        self.path = path
        self.on_error = on_error or (lambda _msg: None)
        self._container: Any = None
        self._frames: Any = None
        self.period_ns = 0
        self.width = self.height = 0

    def open(self) -> None:
        try:
            self._container = av.open(self.path)
        except (av.error.FFmpegError, OSError) as exc:
            raise SourceError(f"cannot open video {self.path}: {exc}") from exc
        if not self._container.streams.video:
            self.close()
            raise SourceError(f"{self.path} has no video stream")
        stream = self._container.streams.video[0]
        stream.thread_type = "AUTO"
        rate = stream.average_rate or stream.guessed_rate
        self.period_ns = int(1e9 / float(rate)) if rate else 0
        self.width, self.height = stream.codec_context.width, stream.codec_context.height
        self._frames = self._decode(stream)

    def _decode(self, stream: Any) -> Any:
        ctx = stream.codec_context
        for packet in self._container.demux(stream):
            try:
                frames = ctx.decode(packet)  # a None packet at the end flushes the decoder
            except av.error.FFmpegError as exc:  # one corrupt packet: count it, go on
                self.on_error(f"{self.path}: undecodable packet ({exc})")
                continue
            for frame in frames:
                yield frame, stream.time_base

    def read(self) -> RawFrame | None:
        for frame, tb in self._frames:
            pts = frame.pts if frame.pts is not None else frame.dts
            pts_ns = None if pts is None or tb is None else round(float(pts * tb) * 1e9)
            return RawFrame("frame", frame, frame.width, frame.height, pts_ns=pts_ns)
        return None

    def rewind(self) -> None:
        self.close()
        self.open()

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
            self._container = None


def _natural_key(name: str) -> list[Any]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


class FolderSource:
    """The images of a folder in natural order (``frame2`` before ``frame10``), one every period."""

    live = False

    def __init__(self, path: str, rate_hz: float):
        self.path = Path(path)
        self.period_ns = int(1e9 / rate_hz)
        self.files: list[Path] = []
        self._i = 0

    def open(self) -> None:
        self.files = sorted((p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
                            key=lambda p: _natural_key(p.name))
        if not self.files:
            raise SourceError(f"folder {self.path} holds no image ({', '.join(IMAGE_SUFFIXES)})")
        self._i = 0

    def read(self) -> RawFrame | None:
        if self._i >= len(self.files):
            return None
        path, i = self.files[self._i], self._i
        self._i += 1
        try:
            if path.suffix.lower() in _JPEG_SUFFIXES:  # kept as it is: maybe no decode at all
                data = path.read_bytes()
                info = jpeg_info(data)
                return RawFrame("jpeg", data, info.width, info.height, pts_ns=i * self.period_ns)
            with av.open(str(path)) as c:
                frame = next(c.decode(video=0))
            return RawFrame("frame", frame, frame.width, frame.height, pts_ns=i * self.period_ns)
        except (av.error.FFmpegError, OSError, ValueError, StopIteration) as exc:
            raise SourceError(f"cannot read image {path}: {exc}") from exc

    def rewind(self) -> None:
        self._i = 0

    def close(self) -> None:
        pass


Source = V4l2Source | FileSource | FolderSource


# -- the capture thread ---------------------------------------------------------------------------

@dataclass
class CaptureStats:
    captured: int = 0
    errors: int = 0
    stamp_fallbacks: int = 0
    loops: int = 0
    eof: bool = False
    reopens: int = 0


class CaptureThread:
    """Reads the source and overwrites the slot, calling ``on_ready`` when an empty slot fills.

    ``pace="realtime"``: a live source as fast as it delivers; a recording at its own timing,
    each frame released (and stamped) at its container time after the start (``PlaybackClock``).
    ``pace="perception"`` (recordings only): a frame is released when ``want`` is set (the
    consumer took the last one), stamped on release, so nothing is dropped whatever the speed.
    """

    def __init__(self, source: Source, slot: LatestSlot[Captured], on_ready: Callable[[], None],
                 on_error: Callable[[str], None], on_eof: Callable[[], None] = lambda: None, *,
                 pace: str = "realtime", loop: bool = False,
                 period_ns: int | None = None, reopen_s: float = 1.0):
        self.source, self.slot, self.on_ready, self.on_error = source, slot, on_ready, on_error
        self.on_eof = on_eof
        self.pace, self.loop, self.period_override = pace, loop, period_ns
        self.reopen_s = reopen_s
        self.want = threading.Event()
        self.want.set()
        self.stop_event = threading.Event()
        self.stats = CaptureStats()
        self._index = 0
        self._last_stamp = 0
        self._thread = threading.Thread(target=self._run, name="camera-capture", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self.stop_event.set()
        self.want.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        try:
            if self.source.live:
                self._run_live()
            else:
                self._run_playback()
        except Exception as exc:  # a bug must not die silently in a thread
            self.stats.errors += 1
            self.on_error(f"capture thread stopped: {exc!r}")

    # live: every buffer as it comes, stamped by the driver
    def _run_live(self) -> None:
        while not self.stop_event.is_set():
            try:
                raw = self.source.read()
            except (SourceError, av.error.FFmpegError, OSError) as exc:
                self.stats.errors += 1
                self.on_error(f"{exc}; reopening in {self.reopen_s:g} s")
                self.source.close()
                while not self.stop_event.wait(self.reopen_s):
                    try:
                        self.source.open()
                        self.stats.reopens += 1
                        break
                    except SourceError as again:
                        self.on_error(str(again))
                continue
            if raw is None:
                continue
            wall, mono = time.time_ns(), time.monotonic_ns()
            stamp = None if raw.driver_ns is None else driver_stamp_to_wall(raw.driver_ns, wall, mono)
            how: Literal["driver", "arrival"] = "driver"
            if stamp is None:
                stamp, how = wall, "arrival"
                self.stats.stamp_fallbacks += 1
            self._put(raw, stamp, how)

    # recordings: the file's timing, or the consumer's
    def _run_playback(self) -> None:
        clock: PlaybackClock | None = None
        pts0: int | None = None
        last_rel, index_in_pass = 0, 0
        period = self.period_override or getattr(self.source, "period_ns", 0) or 100_000_000
        while not self.stop_event.is_set():
            if self.pace == "perception":
                while not self.want.wait(0.5):
                    if self.stop_event.is_set():
                        return
                if self.stop_event.is_set():
                    return
                self.want.clear()
            try:
                raw = self.source.read()
            except SourceError as exc:  # one unreadable image: counted, the next one is tried
                self.stats.errors += 1
                self.on_error(str(exc))
                self.want.set()
                continue
            if raw is None:
                if not self.loop:
                    self.stats.eof = True
                    self.on_eof()
                    return
                if clock is not None:
                    clock.offset_ns += last_rel + period
                pts0, index_in_pass = None, 0
                self.stats.loops += 1
                try:
                    self.source.rewind()
                except SourceError as exc:
                    self.stats.errors += 1
                    self.on_error(str(exc))
                    return
                self.want.set()
                continue
            if self.period_override or raw.pts_ns is None:
                pts = index_in_pass * period
            else:
                pts = raw.pts_ns
            index_in_pass += 1
            if pts0 is None:
                pts0 = pts
            rel = max(pts - pts0, 0)
            last_rel = rel
            if self.pace == "perception":
                self._put(raw, time.time_ns(), "release")
                continue
            if clock is None:
                clock = PlaybackClock(time.time_ns(), time.monotonic_ns())
            delay = (clock.due_mono(rel) - time.monotonic_ns()) / 1e9
            if delay > 0 and self.stop_event.wait(delay):
                return
            self._put(raw, clock.wall(rel), "playback")

    def _put(self, raw: RawFrame, stamp: int, how: Any) -> None:
        stamp = max(stamp, self._last_stamp + 1)  # strictly increasing, whatever a driver does
        self._last_stamp = stamp
        item = Captured(raw, stamp, self._index, how)
        self._index += 1
        self.stats.captured += 1
        if self.slot.put(item):
            self.on_ready()


# -- pixels -------------------------------------------------------------------------------------

class Pixels:
    """Decodes a raw frame to RGB and encodes JPEG; used on the publisher's thread only (the
    codec contexts are not shared with the capture thread)."""

    def __init__(self, jpeg_quality: int = 90):
        # FFmpeg's mjpeg quantiser scale: 2 (best) .. 31; quality 100 → 2, 1 → 31.
        self.qscale = round(2 + (100 - jpeg_quality) * 29 / 99)
        self._decoder: Any = None
        self._encoder: Any = None
        self._enc_size = (0, 0)
        self._pts = 0

    def rgb(self, raw: RawFrame) -> np.ndarray:
        if raw.kind == "frame":
            return raw.data.to_ndarray(format="rgb24")
        if raw.kind == "yuyv":
            buf = np.frombuffer(raw.data, np.uint8)
            if buf.size != raw.width * raw.height * 2:
                raise ValueError(f"YUYV frame of {buf.size} bytes, {raw.width}x{raw.height} needs "
                                 f"{raw.width * raw.height * 2}")
            frame = av.VideoFrame.from_ndarray(buf.reshape(raw.height, raw.width, 2), format="yuyv422")
            return frame.to_ndarray(format="rgb24")
        if self._decoder is None:
            self._decoder = av.CodecContext.create("mjpeg", "r")
        try:
            frames = self._decoder.decode(av.Packet(bytes(raw.data)))
        except av.error.FFmpegError as exc:
            raise ValueError(f"undecodable JPEG frame: {exc}") from exc
        if not frames:
            raise ValueError("undecodable JPEG frame")
        return frames[0].to_ndarray(format="rgb24")

    def jpeg(self, rgb: np.ndarray) -> bytes:
        h, w = rgb.shape[:2]
        if self._encoder is None or self._enc_size != (w, h):
            enc = av.CodecContext.create("mjpeg", "w")
            enc.width, enc.height, enc.pix_fmt = w, h, "yuvj420p"
            enc.time_base = Fraction(1, 1000)
            enc.options = {"qmin": str(self.qscale), "qmax": str(self.qscale)}  # PyAV 12 has no qmin attribute
            self._encoder, self._enc_size = enc, (w, h)
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24").reformat(format="yuvj420p")
        frame.pts = self._pts  # the encoder refuses a frame whose pts does not advance
        self._pts += 1
        packets = self._encoder.encode(frame)
        if not packets:
            raise ValueError("the JPEG encoder returned no packet")
        return bytes(packets[0])
