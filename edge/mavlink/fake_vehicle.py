"""A fake MAVLink vehicle on UDP (pymavlink), for tests and for trying the bridge without an autopilot.

It sends a vehicle ``HEARTBEAT`` (1 Hz), ``LOCAL_POSITION_NED`` and ``ATTITUDE`` (``stream_hz``),
follows velocity + yaw-rate setpoints (``SET_POSITION_TARGET_LOCAL_NED``, BODY_NED or
LOCAL_NED) with a planar kinematic model, holds still when setpoints stop for 0.5 s (like PX4's
offboard loss), and records every setpoint, GCS heartbeat and ``COMMAND_LONG`` it receives.

    python -m riskfield.edge.mavlink.fake_vehicle --url udpout:127.0.0.1:14550
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from dataclasses import dataclass, field

from pymavlink import mavutil

from riskfield.services.geometry.transforms import wrap_angle
from riskfield.services.runtime.signals import stop_event

from .convert import MAV_FRAME_BODY_NED, MAV_FRAME_LOCAL_NED, VELOCITY_YAWRATE_MASK


@dataclass
class VehicleModel:
    """Planar vehicle in NED: follows the velocity setpoint in the horizontal plane and z."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0  # NED: clockwise from north
    vel: tuple[float, float, float] = (0.0, 0.0, 0.0)  # NED
    yaw_rate: float = 0.0
    setpoint_t: float = -math.inf
    hold_after_s: float = 0.5
    ignored: int = 0

    def apply(self, frame: int, type_mask: int, vx: float, vy: float, vz: float, yaw_rate: float, now: float) -> None:
        if type_mask != VELOCITY_YAWRATE_MASK or frame not in (MAV_FRAME_BODY_NED, MAV_FRAME_LOCAL_NED):
            self.ignored += 1
            return
        if frame == MAV_FRAME_BODY_NED:
            c, s = math.cos(self.yaw), math.sin(self.yaw)
            vx, vy = c * vx - s * vy, s * vx + c * vy
        self.vel, self.yaw_rate, self.setpoint_t = (vx, vy, vz), yaw_rate, now

    def step(self, dt: float, now: float) -> None:
        if now - self.setpoint_t > self.hold_after_s:
            self.vel, self.yaw_rate = (0.0, 0.0, 0.0), 0.0
        self.x += self.vel[0] * dt
        self.y += self.vel[1] * dt
        self.z += self.vel[2] * dt
        self.yaw = wrap_angle(self.yaw + self.yaw_rate * dt)


@dataclass
class Received:
    setpoints: list[tuple[float, object]] = field(default_factory=list)
    gcs_heartbeats: list[float] = field(default_factory=list)
    commands: list[object] = field(default_factory=list)


class FakeVehicle:
    """``url`` is the vehicle's side: ``udpout:127.0.0.1:PORT`` talks to a bridge on ``udpin:127.0.0.1:PORT``."""

    def __init__(self, url: str, autopilot: str = "px4", model: VehicleModel | None = None, stream_hz: float = 30.0,
                 system: int = 1, component: int = 1):
        self.url = url
        self.model = model or VehicleModel()
        self.stream_hz = stream_hz
        self.autopilot = (mavutil.mavlink.MAV_AUTOPILOT_PX4 if autopilot == "px4"
                          else mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
        self.received = Received()
        self.lock = threading.Lock()
        self.conn = mavutil.mavlink_connection(url, source_system=system, source_component=component)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._boot = time.monotonic()

    def start(self) -> FakeVehicle:
        self._thread = threading.Thread(target=self._run, name="fake-vehicle", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.conn.close()

    def __enter__(self) -> FakeVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def setpoints(self) -> list[tuple[float, object]]:
        with self.lock:
            return list(self.received.setpoints)

    def _run(self) -> None:
        mav = self.conn.mav
        period = 1.0 / self.stream_hz
        last = time.monotonic()
        next_stream, next_hb = last, last
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                next_hb = now + 1.0
                mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GROUND_ROVER, self.autopilot, 0, 0, 0)
            if now >= next_stream:
                next_stream = now + period
                m = self.model
                m.step(now - last, now)
                last = now
                ms = int((now - self._boot) * 1000)
                mav.local_position_ned_send(ms, m.x, m.y, m.z, *m.vel)
                mav.attitude_send(ms, 0.0, 0.0, m.yaw, 0.0, 0.0, m.yaw_rate)
            msg = self.conn.recv_match(blocking=True, timeout=max(0.0, min(next_stream, next_hb) - time.monotonic()))
            while msg is not None:
                self._handle(msg, time.monotonic())
                msg = self.conn.recv_match(blocking=False)

    def _handle(self, msg: object, now: float) -> None:
        kind = msg.get_type()
        with self.lock:
            if kind == "SET_POSITION_TARGET_LOCAL_NED":
                self.received.setpoints.append((time.perf_counter(), msg))
                self.model.apply(msg.coordinate_frame, msg.type_mask, msg.vx, msg.vy, msg.vz, msg.yaw_rate, now)
            elif kind == "HEARTBEAT" and msg.type == mavutil.mavlink.MAV_TYPE_GCS:
                self.received.gcs_heartbeats.append(now)
            elif kind == "COMMAND_LONG":
                self.received.commands.append(msg)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="A fake MAVLink ground vehicle on UDP.")
    ap.add_argument("--url", default="udpout:127.0.0.1:14550")
    ap.add_argument("--autopilot", choices=["px4", "ardupilot"], default="px4")
    args = ap.parse_args(argv)
    stop = stop_event()
    with FakeVehicle(args.url, args.autopilot) as v:
        print(f"fake {args.autopilot} vehicle → {args.url}", flush=True)
        while not stop.wait(1.0):
            m = v.model
            print(f"N={m.x:+.2f} E={m.y:+.2f} yaw={math.degrees(m.yaw):+.0f}° setpoints={len(v.setpoints())}",
                  flush=True)


if __name__ == "__main__":
    main()
