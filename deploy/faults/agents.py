"""Small Zenoh programs the fault drills run inside the robot and server namespaces.

    python deploy/faults/agents.py esdf-source  --connect EP --robot ID [--rate 10]
    python deploy/faults/agents.py frame-source --connect EP --robot ID [--rate 10]
    python deploy/faults/agents.py robot-inputs --connect EP --robot ID [--speed 0.3]
    python deploy/faults/agents.py probe        --connect EP --robot ID --out FILE

``esdf-source`` stands in for mapping (a free-space ESDF slice), ``frame-source`` for
perception (a pointmap of a wall 3 m ahead, which the real mapping service turns into an
ESDF), ``robot-inputs`` for the robot bridge and the joystick (state at 50 Hz, a forward
reference at 30 Hz), and ``probe`` records what the robot side hears: the arrival time
(CLOCK_MONOTONIC, shared by every namespace of the machine) of each ESDF with its content stamp,
each ``cmd/safe`` with its velocities and the wall clock it was computed at (its stamp), each
``safety/status`` with its fallback, one JSON object per line.

They use the wire contract (``riskfield.protocol``) and a plain Zenoh client session (built by
the runtime's ``endpoint_config``); each
stops cleanly on SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections.abc import Callable

import numpy as np
import zenoh

from riskfield.protocol import (
    ENCODING,
    EsdfGrid,
    Keys,
    PerceptionFrame,
    RobotState,
    SafetyStatus,
    VelocityCommand,
    ade20k,
    decode,
    encode,
)
from riskfield.services.runtime.session import endpoint_config
from riskfield.services.runtime.signals import stop_event

_ENC = zenoh.Encoding(ENCODING)


def open_session(endpoint: str) -> zenoh.Session:
    # Keep retrying the first connection: the router may still be starting.
    return zenoh.open(endpoint_config("client", [endpoint],
                                      extra={"connect/timeout_ms": -1, "connect/exit_on_failure": False}))


def every(period_s: float, stop: threading.Event, fn: Callable[[], None]) -> None:
    """Call ``fn`` every ``period_s`` on a fixed schedule (no catch-up bursts) until ``stop``."""
    nxt = time.monotonic()
    while not stop.is_set():
        fn()
        nxt += period_s
        delay = nxt - time.monotonic()
        if delay < 0:
            nxt, delay = time.monotonic(), 0.0
        stop.wait(delay)


def free_space_esdf() -> EsdfGrid:
    """A 6 m × 6 m slice around the origin, 1.5 m from any obstacle everywhere."""
    n = 60
    return EsdfGrid(origin=(-3.0, -3.0, 0.0), voxel_size=0.1, distance=np.full((n, n, 1), 1.5, np.float32),
                    risk_group=np.zeros((n, n, 1), np.uint8), groups=["high", "mid", "low"], max_distance=2.0,
                    unknown_is_occupied=False)


def wall_frame(keyframe_id: int, width: int = 64, height: int = 48) -> PerceptionFrame:
    """A camera 0.2 m above the floor at the origin looking along +x at a wall 3 m ahead."""
    f = 0.8 * width
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    z = np.full((height, width), 3.0)
    points = np.stack([(u - width / 2) / f * z, (v - height / 2) / f * z, z], axis=-1).astype(np.float32)
    # camera (x right, y down, z forward) → world (x forward, y left, z up)
    T_WC = np.eye(4)
    T_WC[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    T_WC[2, 3] = 0.2
    return PerceptionFrame(T_WC=T_WC, points=points, confidence=np.ones((height, width), np.float32),
                           labels=np.full((height, width), ade20k.index("wall"), np.uint16), keyframe_id=keyframe_id)


def publisher_loop(args: argparse.Namespace, key: str, make: Callable[[int], object]) -> None:
    stop = stop_event()
    session = open_session(args.connect)
    pub = session.declare_publisher(key, encoding=_ENC)
    count = [0]

    def tick() -> None:
        msg = make(count[0])
        msg.header.seq = count[0]  # type: ignore[attr-defined]
        msg.header.stamp_ns = time.time_ns()  # type: ignore[attr-defined]
        pub.put(encode(msg))  # type: ignore[arg-type]
        count[0] += 1

    try:
        every(1.0 / args.rate, stop, tick)
    finally:
        session.close()


def esdf_source(args: argparse.Namespace) -> None:
    grid = free_space_esdf()
    publisher_loop(args, Keys(robot=args.robot).esdf, lambda i: grid)


def frame_source(args: argparse.Namespace) -> None:
    frame = wall_frame(0)
    publisher_loop(args, Keys(robot=args.robot).perception_frame, lambda i: frame)


def robot_inputs(args: argparse.Namespace) -> None:
    stop = stop_event()
    keys = Keys(robot=args.robot)
    session = open_session(args.connect)
    state_pub = session.declare_publisher(keys.state, encoding=_ENC)
    ref_pub = session.declare_publisher(keys.cmd_ref, encoding=_ENC)

    def state() -> None:
        state_pub.put(encode(RobotState(position=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0),
                                        linear_velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0))))

    def ref() -> None:
        ref_pub.put(encode(VelocityCommand(linear=(args.speed, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="teleop")))

    threading.Thread(target=every, args=(1 / 30, stop, ref), daemon=True).start()
    try:
        every(1 / 50, stop, state)
    finally:
        session.close()


def probe(args: argparse.Namespace) -> None:
    stop = stop_event()
    keys = Keys(robot=args.robot)
    lock = threading.Lock()
    out = open(args.out, "a", buffering=1)  # line-buffered: a reader sees whole events

    def write(record: dict) -> None:
        with lock:
            out.write(json.dumps(record) + "\n")

    def on_esdf(sample: zenoh.Sample) -> None:
        t = time.monotonic()
        grid = decode(sample.payload.to_bytes(), EsdfGrid)
        write({"t": t, "k": "esdf", "key": str(sample.key_expr), "stamp_ns": grid.header.stamp_ns})

    def on_cmd(sample: zenoh.Sample) -> None:
        t = time.monotonic()
        cmd = decode(sample.payload.to_bytes(), VelocityCommand)
        write({"t": t, "k": "cmd", "linear": list(cmd.linear), "angular": list(cmd.angular),
               "stamp_ns": cmd.header.stamp_ns})

    def on_status(sample: zenoh.Sample) -> None:
        t = time.monotonic()
        st = decode(sample.payload.to_bytes(), SafetyStatus)
        write({"t": t, "k": "status", "fallback": st.fallback, "esdf_age_ms": st.esdf_age_ms})

    session = open_session(args.connect)
    subs = [session.declare_subscriber(keys.esdf, on_esdf),
            session.declare_subscriber(keys.cmd_safe, on_cmd),
            session.declare_subscriber(keys.safety_status, on_status)]
    write({"t": time.monotonic(), "k": "probe_up"})
    try:
        stop.wait()
    finally:
        for s in subs:
            s.undeclare()
        session.close()
        out.close()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("role", choices=["esdf-source", "frame-source", "robot-inputs", "probe"])
    parser.add_argument("--connect", required=True, help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--robot", default="limo1")
    parser.add_argument("--rate", type=float, default=10.0, help="publication rate (sources), Hz")
    parser.add_argument("--speed", type=float, default=0.3, help="forward reference speed (robot-inputs), m/s")
    parser.add_argument("--out", help="JSON-lines file (probe)")
    args = parser.parse_args(argv)
    {"esdf-source": esdf_source, "frame-source": frame_source, "robot-inputs": robot_inputs, "probe": probe}[
        args.role](args)


if __name__ == "__main__":
    main()
