"""A LIMO chassis emulator on a pseudo-terminal, speaking the real serial framing.

``ChassisModel`` is the pure part: it obeys ``0x421``/``0x111`` frames, integrates a planar
model of the chosen motion mode (unicycle, bicycle or holonomic) and produces the feedback
frames a LIMO sends (``0x211``, ``0x221``, ``0x311``, ``0x321``, ``0x322``, ``0x323``).
Like the real chassis it ignores motion frames until serial command mode is enabled.
In Ackermann mode it reads the steering field and reports the steering feedback with the
conversions of ``ackermann`` (the bridge's own, so the two agree by construction): the field
times 1.64 is the inner wheel's angle, clamped to its limit, and the feedback field is that
angle divided by 2.47 (left) or 1.64 (right). The mecanum form of the ``0x421`` frame (d2 = 1)
switches it to mecanum; ``reported_mode`` makes ``0x211`` d6 say something else (a chassis
with mecanum wheels that reports 0). It keeps the last motion command until another comes:
it has no command timeout, because no AgileX source states one for the chassis.

``ChassisEmulator`` puts a model behind a pty (``os.openpty``): the bridge opens the slave
path like a serial device, a thread reads the master side, and feedback goes out at
``rate_hz``. ``link`` makes a stable symlink to the current pty; ``disconnect()`` closes
the pty (the port "disappears") and ``reconnect()`` opens a new one and re-points the link.

Run it by hand::

    python -m riskfield.edge.limo.emulator --link /tmp/limo
    RISKFIELD_LIMO_PORT=/tmp/limo riskfield run limo
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import select
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass

from riskfield.protocol.platforms import LIMO
from riskfield.services.geometry.transforms import wrap_angle
from riskfield.services.runtime.signals import stop_event

from . import ackermann
from .kinematics import MotionMode
from .protocol import (
    ControlModeCommand,
    FrameParser,
    ImuAccel,
    ImuEuler,
    ImuGyro,
    MotionCommand,
    MotionState,
    Odometry,
    SystemState,
    decode,
    encode,
)


@dataclass
class ChassisModel:
    motion_mode: MotionMode = MotionMode.DIFFERENTIAL
    wheelbase: float = LIMO.wheelbase
    track: float = LIMO.track
    max_inner_steering: float = LIMO.max_steering  # the inner wheel's mechanical limit (rad)
    reported_mode: int | None = None  # 0x211 d6 when it is not the motion mode (None: the mode)
    battery_v: float = 12.1
    error_bits: int = 0
    control_mode: int = 0  # 0 standby until 0x421 enables serial command mode (1)
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    left: float = 0.0
    right: float = 0.0
    v: float = 0.0
    vy: float = 0.0
    w: float = 0.0
    steering: float = 0.0  # the 0x221 steering field (Ackermann: the inner angle / 2.47 or / 1.64)
    inner: float = 0.0  # the inner front wheel's angle (rad), Ackermann
    yaw_offset: float = 0.0  # the IMU's yaw at the start (a real IMU is not aligned with the map)

    def apply(self, msg: object) -> None:
        if isinstance(msg, ControlModeCommand):
            self.control_mode = 1 if msg.enable else 0
            if msg.enable and msg.mecanum:
                self.motion_mode = MotionMode.MECANUM
            if not msg.enable:
                self.v = self.vy = self.w = 0.0
        elif isinstance(msg, MotionCommand) and self.control_mode == 1:
            self.v = msg.linear
            if self.motion_mode == MotionMode.ACKERMANN:
                lim = self.max_inner_steering
                self.inner = max(-lim, min(lim, ackermann.inner_from_command_field(msg.steering)))
                self.steering = ackermann.feedback_field(self.inner)
                central = ackermann.inner_to_central(self.inner, self.wheelbase, self.track)
                self.w = msg.linear * math.tan(central) / self.wheelbase
                self.vy = 0.0
            else:
                self.w = msg.angular
                self.vy = msg.lateral if self.motion_mode == MotionMode.MECANUM else 0.0

    def step(self, dt: float) -> None:
        mid = self.yaw + 0.5 * self.w * dt
        c, s = math.cos(mid), math.sin(mid)
        self.x += (self.v * c - self.vy * s) * dt
        self.y += (self.v * s + self.vy * c) * dt
        self.yaw = wrap_angle(self.yaw + self.w * dt)
        self.left += (self.v - self.w * self.track / 2) * dt
        self.right += (self.v + self.w * self.track / 2) * dt

    def feedback(self) -> bytes:
        return b"".join(encode(m) for m in (
            SystemState(vehicle_state=0, control_mode=self.control_mode, battery_v=self.battery_v,
                        error_bits=self.error_bits,
                        motion_mode=int(self.motion_mode) if self.reported_mode is None else self.reported_mode),
            MotionState(self.v, self.w, self.vy, self.steering),
            Odometry(self.left, self.right),
            ImuAccel(0.0, 0.0, 9.81),
            ImuGyro(0.0, 0.0, self.w),
            ImuEuler(wrap_angle(self.yaw + self.yaw_offset), 0.0, 0.0),
        ))


class ChassisEmulator:
    """A ``ChassisModel`` on a pty, served by a thread. Use as a context manager.

    ``received`` lists ``(time.perf_counter(), message)`` for every valid frame received;
    ``on_frame(t, message)`` (optional) is called from the emulator thread as each arrives.
    """

    def __init__(self, model: ChassisModel | None = None, rate_hz: float = 50.0, link: str | None = None,
                 on_frame: Callable[[float, object], None] | None = None, feedback: bool = True):
        self.model = model or ChassisModel()
        self.rate_hz = rate_hz
        self.link = link
        self.on_frame = on_frame
        self.send_feedback = feedback
        self.parser = FrameParser()
        self.received: list[tuple[float, object]] = []
        self._lock = threading.Lock()
        self._master = -1
        self._slave = -1
        self.path = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._wake_r, self._wake_w = os.pipe()

    # -- pty ------------------------------------------------------------------------------------
    def _open_pty(self) -> None:
        master, slave = os.openpty()
        # Raw mode at once: the default line discipline would echo bytes and translate 0x0D.
        tty.setraw(slave)
        tty.setraw(master)
        # A UART drops what nobody reads; a blocking write into a full pty would stall the chassis
        # (and, holding the lock, its stop) once the bridge has gone.
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.path = os.ttyname(slave)
        self.parser.reset()
        if self.link:
            tmp = f"{self.link}.tmp{os.getpid()}"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(self.path, tmp)
            os.replace(tmp, self.link)

    def _close_pty(self) -> None:
        for fd in (self._master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = -1

    def disconnect(self) -> None:
        """The port disappears: close both ends and remove the link."""
        with self._lock:
            self._close_pty()
            if self.link:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.link)
        os.write(self._wake_w, b"x")

    def reconnect(self) -> str:
        """A new pty appears (new path), and the link points to it."""
        with self._lock:
            self._close_pty()
            self._open_pty()
        os.write(self._wake_w, b"x")
        return self.path

    @property
    def port(self) -> str:
        """What a bridge should open: the link when there is one, else the pty path."""
        return self.link or self.path

    # -- I/O ------------------------------------------------------------------------------------
    def inject(self, data: bytes) -> None:
        """Write raw bytes to the bridge (noise, corrupt frames)."""
        with self._lock:
            if self._master >= 0:
                os.write(self._master, data)

    def frames(self, kind: type | None = None) -> list[tuple[float, object]]:
        with self._lock:
            return [(t, m) for t, m in self.received if kind is None or isinstance(m, kind)]

    def start(self) -> ChassisEmulator:
        self._open_pty()
        self._thread = threading.Thread(target=self._run, name="limo-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(5.0)
        with self._lock:
            self._close_pty()
            if self.link:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.link)
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> ChassisEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        last = time.monotonic()
        next_fb = last + period
        while not self._stop.is_set():
            master = self._master
            fds = [self._wake_r] + ([master] if master >= 0 else [])
            timeout = max(0.0, next_fb - time.monotonic())
            try:
                ready, _, _ = select.select(fds, [], [], timeout)
            except (OSError, ValueError):  # the fd was closed under us by disconnect()
                continue
            if self._wake_r in ready:
                os.read(self._wake_r, 64)
            if master in ready:
                self._receive(master)
            now = time.monotonic()
            if now >= next_fb:
                self.model.step(now - last)
                last = now
                next_fb = max(next_fb + period, now)
                if self.send_feedback:
                    with self._lock:
                        if self._master >= 0:
                            with contextlib.suppress(OSError):
                                os.write(self._master, self.model.feedback())

    def _receive(self, master: int) -> None:
        try:
            data = os.read(master, 4096)
        except OSError:
            return
        t = time.perf_counter()
        for frame in self.parser.feed(data):
            msg = decode(frame)
            if msg is None:
                continue
            self.model.apply(msg)
            with self._lock:
                self.received.append((t, msg))
                if len(self.received) > 100_000:
                    del self.received[:50_000]
            if self.on_frame is not None:
                self.on_frame(t, msg)


def command_logger(now: Callable[[], float] = time.time) -> Callable[[float, object], None]:
    """An ``on_frame`` that prints every change between moving and stopped motion commands reaching
    the serial link, with the wall-clock time (the host's, which containers share), so that a test
    can tell when a zero command arrived after a network cut::

        limo-emulator: 1764662400.123456 stop v=+0.000 w=+0.000
    """
    last: list[bool | None] = [None]

    def on_frame(_t: float, msg: object) -> None:
        if not isinstance(msg, MotionCommand):
            return
        moving = not msg.is_stop
        if moving != last[0]:
            last[0] = moving
            print(f"limo-emulator: {now():.6f} {'move' if moving else 'stop'} v={msg.linear:+.3f} w={msg.angular:+.3f}",
                  flush=True)

    return on_frame


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Emulate an AgileX LIMO chassis on a pseudo-terminal.")
    ap.add_argument("--link", help="symlink to create for the pty (e.g. /tmp/limo)")
    ap.add_argument("--mode", default="differential", help="differential, ackermann or mecanum")
    ap.add_argument("--rate", type=float, default=50.0, help="feedback rate (Hz)")
    ap.add_argument("--log-commands", action="store_true",
                    help="print every move/stop change of the commands reaching the link (command_logger)")
    args = ap.parse_args(argv)
    model = ChassisModel(motion_mode=MotionMode.parse(args.mode))
    stop = stop_event()
    on_frame = command_logger() if args.log_commands else None
    with ChassisEmulator(model, rate_hz=args.rate, link=args.link, on_frame=on_frame) as emu:
        print(f"LIMO emulator ({model.motion_mode.name.lower()}) on {emu.path}"
              + (f" (link {args.link})" if args.link else ""), flush=True)
        while not stop.wait(1.0):
            m = emu.model
            print(f"x={m.x:+.2f} y={m.y:+.2f} yaw={math.degrees(m.yaw):+.0f}° v={m.v:+.2f} w={m.w:+.2f} "
                  f"mode={m.control_mode}", flush=True)


if __name__ == "__main__":
    main()
