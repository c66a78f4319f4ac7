"""The one-frame hand-over between the capture thread and the publisher, and the capture stamps.

A camera is a stream where only the newest frame matters (DESIGN, "latest-value queues"): the
capture thread overwrites one slot, the publisher takes whatever is newest, and a frame
overwritten before anyone took it is a drop, counted. There is never a queue, so a slow
publisher (a JPEG encode, a busy core) costs frames, never latency.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")


class LatestSlot(Generic[T]):
    """Thread-safe single slot: ``put`` overwrites, ``take`` empties; counts what was overwritten."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._item: T | None = None
        self.put_count = 0
        self.dropped = 0

    def put(self, item: T) -> bool:
        """Store ``item``; True when the slot was empty (the taker needs waking), False when an
        untaken frame was overwritten (a drop)."""
        with self._lock:
            self.put_count += 1
            was_empty = self._item is None
            if not was_empty:
                self.dropped += 1
            self._item = item
            return was_empty

    def take(self) -> T | None:
        with self._lock:
            item, self._item = self._item, None
            return item


# -- stamps -------------------------------------------------------------------------------------

KERNEL_WINDOW_NS = (10_000_000_000, 1_000_000_000)
"""How far in the past / future a driver timestamp may lie from "now" on a clock to be read as that
clock's (FFmpeg's v4l2 demuxer uses the same window to tell wall-clock from monotonic stamps:
libavdevice/v4l2.c, ``init_convert_timestamp``)."""


def driver_stamp_to_wall(ts_ns: int, wall_ns: int, mono_ns: int) -> int | None:
    """A V4L2 buffer timestamp (ns, as the driver set it) on the wall clock, or None if it is on
    neither clock. UVC and most drivers stamp with CLOCK_MONOTONIC (``V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC``)
    at the start of the frame; it is moved to the wall clock by the offset between the two clocks
    read now. A stamp already on the wall clock (uvcvideo's ``clock=realtime``) is kept."""
    past, future = KERNEL_WINDOW_NS
    if wall_ns - past <= ts_ns <= wall_ns + future:
        return ts_ns
    if mono_ns - past <= ts_ns <= mono_ns + future:
        return ts_ns + (wall_ns - mono_ns)
    return None


@dataclass
class PlaybackClock:
    """Capture times of a played-back recording: the first frame is "captured" when playback
    starts, each later one at its container time after it (``pts`` mapped to the wall clock), and a
    loop continues where the previous pass ended, so stamps keep increasing."""

    wall0_ns: int
    mono0_ns: int
    offset_ns: int = 0  # media time of the passes already played

    def media_ns(self, pts_ns: int) -> int:
        return self.offset_ns + pts_ns

    def wall(self, pts_ns: int) -> int:
        return self.wall0_ns + self.media_ns(pts_ns)

    def due_mono(self, pts_ns: int) -> int:
        return self.mono0_ns + self.media_ns(pts_ns)
