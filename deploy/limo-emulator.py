"""The project's LIMO chassis emulator (riskfield.edge.limo.emulator) for a container without a
LIMO: deploy/compose.limo-emulator.yml runs it beside the `limo` bridge, which opens its
pseudo-terminal as its serial port (a pty cannot be shared between containers).

Every change between moving and stopped commands that reaches the emulated chassis's serial link
is logged with the wall-clock time (the host's clock: containers share it), so that a test can
tell when a zero command arrived after a network cut:

    limo-emulator: 1764662400.123456 stop v=+0.000 w=+0.000
"""

from __future__ import annotations

import argparse
import time

from riskfield.edge.limo.emulator import ChassisEmulator, ChassisModel
from riskfield.edge.limo.kinematics import MotionMode
from riskfield.edge.limo.protocol import MotionCommand
from riskfield.services.runtime.signals import stop_event


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--link", default="/tmp/limo", help="symlink the bridge opens as its serial port")
    ap.add_argument("--mode", default="differential", help="differential, ackermann or mecanum")
    args = ap.parse_args()
    last: list[bool | None] = [None]

    def on_frame(_t: float, msg: object) -> None:
        if not isinstance(msg, MotionCommand):
            return
        moving = not msg.is_stop
        if moving != last[0]:
            last[0] = moving
            print(f"limo-emulator: {time.time():.6f} {'move' if moving else 'stop'} "
                  f"v={msg.linear:+.3f} w={msg.angular:+.3f}", flush=True)

    model = ChassisModel(motion_mode=MotionMode.parse(args.mode))
    stop = stop_event()
    with ChassisEmulator(model, link=args.link, on_frame=on_frame) as emu:
        print(f"limo-emulator: chassis on {emu.path} (link {args.link})", flush=True)
        while not stop.wait(5.0):
            m = emu.model
            print(f"limo-emulator: {time.time():.6f} x={m.x:+.2f} y={m.y:+.2f} v={m.v:+.2f} w={m.w:+.2f} "
                  f"mode={m.control_mode}", flush=True)


if __name__ == "__main__":
    main()
