"""Where joystick events come from: a real evdev device, a raw event stream, or a recording.

Every source has the same three calls: ``open()`` (→ ``DeviceInfo`` or ``DeviceUnavailable``),
``read()`` (the events waiting now, never blocking; ``DeviceLost`` when the device went away)
and ``close()``, plus ``fileno()`` (a descriptor to wait on, or −1). Events are
``InputEvent(t, type, code, value)`` exactly as the kernel reports them, packets ending with
``EV_SYN/SYN_REPORT``.

* ``EvdevSource`` — python-evdev (imported only when used): finds the Extreme 3D Pro by USB
  id 046d:c215, or opens ``device`` (``RISKFIELD_JOYSTICK_DEVICE``); reads the axis ranges and
  the current axis/button state at open.
* ``RawEventSource`` — reads ``struct input_event`` records (what ``/dev/input/eventN`` yields)
  from a path: a device node, a FIFO another process writes, or a captured file.
* ``RecordedSource`` — replays in-memory sequences with their timing; each ``open()`` starts
  the next session, so device loss and reconnection can be scripted.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import stat
import struct
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

from .mapping import EV_SYN, SYN_REPORT

LOGITECH_EXTREME_3D_PRO = (0x046D, 0xC215)


class InputEvent(NamedTuple):
    t: float
    type: int
    code: int
    value: int


@dataclass
class DeviceInfo:
    name: str
    path: str = ""
    ranges: dict[int, tuple[int, int]] = field(default_factory=dict)  # axis code → (min, max)
    axes: dict[int, int] = field(default_factory=dict)  # axis code → value at open
    buttons: dict[int, int] = field(default_factory=dict)  # button code → 1 if held at open


class DeviceUnavailable(RuntimeError):
    """No device to open (yet)."""


class DeviceLost(RuntimeError):
    """The device disappeared while open."""


class EventSource(Protocol):
    def open(self) -> DeviceInfo: ...
    def read(self) -> list[InputEvent]: ...
    def close(self) -> None: ...

    def fileno(self) -> int:
        """A descriptor that becomes readable when events wait (−1: none, poll ``read``)."""
        ...


# -- evdev ------------------------------------------------------------------------------------


class EvdevSource:
    def __init__(self, device: str | None = None, ids: tuple[int, int] = LOGITECH_EXTREME_3D_PRO):
        self.device_path = device or os.environ.get("RISKFIELD_JOYSTICK_DEVICE") or None
        self.ids = ids
        self._dev = None

    def _find(self) -> str:
        import evdev  # lazily: the light install and the tests need no input subsystem

        if self.device_path:
            if not os.path.exists(self.device_path):
                raise DeviceUnavailable(f"{self.device_path} does not exist")
            return self.device_path
        for path in evdev.list_devices():
            with contextlib.suppress(OSError):
                dev = evdev.InputDevice(path)
                match = (dev.info.vendor, dev.info.product) == self.ids
                dev.close()
                if match:
                    return path
        raise DeviceUnavailable(f"no input device with USB id {self.ids[0]:04x}:{self.ids[1]:04x}")

    def open(self) -> DeviceInfo:
        import evdev

        path = self._find()
        try:
            dev = evdev.InputDevice(path)
        except OSError as exc:
            raise DeviceUnavailable(f"cannot open {path}: {exc}") from None
        self._dev = dev
        info = DeviceInfo(name=dev.name, path=path)
        for code, absinfo in dev.capabilities().get(evdev.ecodes.EV_ABS, []):
            info.ranges[code] = (absinfo.min, absinfo.max)
            info.axes[code] = absinfo.value
        info.buttons = {code: 1 for code in dev.active_keys()}
        return info

    def read(self) -> list[InputEvent]:
        if self._dev is None:
            return []
        try:
            return [InputEvent(e.timestamp(), e.type, e.code, e.value) for e in self._dev.read()]
        except BlockingIOError:
            return []
        except OSError as exc:
            self.close()
            raise DeviceLost(str(exc)) from None

    def close(self) -> None:
        if self._dev is not None:
            with contextlib.suppress(OSError):
                self._dev.close()
            self._dev = None

    def fileno(self) -> int:
        return -1 if self._dev is None else self._dev.fd


# -- raw struct input_event -------------------------------------------------------------------

#: ``struct input_event`` on 64-bit Linux: timeval (two longs), u16 type, u16 code, s32 value.
INPUT_EVENT = struct.Struct("llHHi")


def pack_event(type_: int, code: int, value: int, t: float | None = None) -> bytes:
    t = time.time() if t is None else t
    sec = int(t)
    return INPUT_EVENT.pack(sec, int((t - sec) * 1e6), type_, code, value)


class RawEventSource:
    """``struct input_event`` records from ``path`` (device node, FIFO or file), non-blocking.

    No ranges or initial state are known: the mapping's defaults apply and axes start centred."""

    def __init__(self, path: str):
        self.path = path
        self._fd = -1
        self._buf = b""
        self._fifo = False
        self._waitable = False

    def open(self) -> DeviceInfo:
        try:
            self._fd = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK)
            mode = os.fstat(self._fd).st_mode
        except OSError as exc:
            self.close()
            raise DeviceUnavailable(f"cannot open {self.path}: {exc}") from None
        self._fifo = stat.S_ISFIFO(mode)
        self._waitable = self._fifo or stat.S_ISCHR(mode)  # a regular file is always "readable"
        self._buf = b""
        return DeviceInfo(name=f"raw events from {self.path}", path=self.path)

    def fileno(self) -> int:
        return self._fd if self._waitable else -1

    def read(self) -> list[InputEvent]:
        if self._fd < 0:
            return []
        try:
            data = os.read(self._fd, 64 * INPUT_EVENT.size)
        except BlockingIOError:
            return []
        except OSError as exc:
            if exc.errno == errno.EAGAIN:
                return []
            self.close()
            raise DeviceLost(f"{self.path}: {exc}") from None
        if not data and self._fifo:
            # The writer closed: a FIFO then stays "readable" (hang-up) forever. Reopening
            # waits quietly for the next writer instead.
            os.close(self._fd)
            self._fd = -1
            try:
                self._fd = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK)
            except OSError as exc:
                raise DeviceLost(f"{self.path}: {exc}") from None
        buf = self._buf + data  # b"" from a regular file: its end, nothing new yet
        n = len(buf) - len(buf) % INPUT_EVENT.size
        self._buf = buf[n:]
        out = []
        for off in range(0, n, INPUT_EVENT.size):
            sec, usec, type_, code, value = INPUT_EVENT.unpack_from(buf, off)
            out.append(InputEvent(sec + usec * 1e-6, type_, code, value))
        return out

    def close(self) -> None:
        if self._fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = -1


# -- recordings -------------------------------------------------------------------------------


@dataclass
class Session:
    """One connection of a recorded device: events at times relative to ``open()``, then
    (optionally) the device is lost at ``lost_at``."""

    events: Sequence[tuple[float, int, int, int]]
    info: DeviceInfo = field(default_factory=lambda: DeviceInfo(name="recorded Extreme 3D Pro"))
    lost_at: float | None = None


def packets(*steps: tuple[float, Sequence[tuple[int, int, int]]]) -> list[tuple[float, int, int, int]]:
    """``(t, [(type, code, value), ...])`` steps → events with a SYN_REPORT closing each packet."""
    out = []
    for t, events in steps:
        out += [(t, ty, c, v) for ty, c, v in events]
        out.append((t, EV_SYN, SYN_REPORT, 0))
    return out


class RecordedSource:
    """Replays ``sessions`` one per ``open()``; ``clock`` is injectable for exact unit tests."""

    def __init__(self, sessions: Sequence[Session], clock: Callable[[], float] = time.monotonic):
        self.sessions = list(sessions)
        self.clock = clock
        self.opened = 0
        self._current: Session | None = None
        self._t0 = 0.0
        self._next = 0

    def open(self) -> DeviceInfo:
        if self.opened >= len(self.sessions):
            raise DeviceUnavailable("the recording has no more sessions")
        self._current = self.sessions[self.opened]
        self.opened += 1
        self._t0 = self.clock()
        self._next = 0
        return self._current.info

    def read(self) -> list[InputEvent]:
        s = self._current
        if s is None:
            return []
        elapsed = self.clock() - self._t0
        out = []
        while self._next < len(s.events) and s.events[self._next][0] <= elapsed:
            t, ty, c, v = s.events[self._next]
            out.append(InputEvent(self._t0 + t, ty, c, v))
            self._next += 1
        if s.lost_at is not None and elapsed >= s.lost_at and not out:
            self._current = None  # events before the loss are delivered first, the loss on the next read
            raise DeviceLost("recorded device loss")
        return out

    def close(self) -> None:
        self._current = None

    def fileno(self) -> int:
        return -1


def load_recording(path: str) -> RecordedSource:
    """A JSON recording: ``{"sessions": [{"events": [[t, type, code, value], ...],
    "lost_at": t | null, "ranges": {code: [min, max]}, "axes": {code: value}, "buttons": {code: 1}}]}``."""
    try:
        with open(path) as f:
            doc = json.load(f)
        sessions = []
        for s in doc["sessions"]:
            info = DeviceInfo(
                name=s.get("name", f"recording {os.path.basename(path)}"), path=path,
                ranges={int(k): (int(v[0]), int(v[1])) for k, v in s.get("ranges", {}).items()},
                axes={int(k): int(v) for k, v in s.get("axes", {}).items()},
                buttons={int(k): int(v) for k, v in s.get("buttons", {}).items()},
            )
            events = [(float(t), int(ty), int(c), int(v)) for t, ty, c, v in s["events"]]
            lost = s.get("lost_at")
            sessions.append(Session(events, info, None if lost is None else float(lost)))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"joystick recording {path}: {exc}") from None
    return RecordedSource(sessions)
