"""Keyboard teleop in a terminal, for people without a joystick (``riskfield run keyboard``).

Keys: ``w``/↑ faster, ``s``/↓ slower (or reverse), ``a``/← turn left, ``d``/→ turn right,
``q``/``e`` strafe left/right (mecanum), space or ``x`` stop. Each press changes the command
by one step; holding a key repeats it. A terminal reports no key releases, so the command
falls back to zero when no key has arrived for ``hold_s`` (a dead-man: let go of the
keyboard and the robot stops). Ctrl-C quits.

``KeyboardTeleop`` and ``parse_keys`` are pure; ``KeyboardNode`` puts stdin in cbreak mode
(Ctrl-C still raises SIGINT) and restores it on exit.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import sys
import termios
import time
import tty
from dataclasses import dataclass
from typing import ClassVar

from pydantic import Field

from riskfield.protocol import VelocityCommand
from riskfield.services.runtime import Node, NodeSettings, ServiceSpec

_ESCAPES = {b"\x1b[A": "up", b"\x1b[B": "down", b"\x1b[C": "right", b"\x1b[D": "left",
            b"\x1bOA": "up", b"\x1bOB": "down", b"\x1bOC": "right", b"\x1bOD": "left"}


def parse_keys(data: bytes) -> list[str]:
    """Terminal bytes → key names (arrow escape sequences become ``up``/``down``/…)."""
    keys, i = [], 0
    while i < len(data):
        seq = data[i:i + 3]
        if seq in _ESCAPES:
            keys.append(_ESCAPES[seq])
            i += 3
            continue
        ch = data[i:i + 1]
        keys.append("space" if ch == b" " else ch.decode("latin-1").lower())
        i += 1
    return keys


@dataclass
class KeyboardTeleop:
    step_linear: float = 0.05
    step_angular: float = 0.2
    max_linear: float = 0.5
    max_lateral: float = 0.3
    max_angular: float = 1.0
    hold_s: float = 1.0
    vx: float = 0.0
    vy: float = 0.0
    wz: float = 0.0
    last_key_t: float = -math.inf

    def on_key(self, key: str, now: float) -> None:
        clamp = lambda v, m: max(-m, min(m, v))  # noqa: E731
        if key in ("w", "up"):
            self.vx = clamp(self.vx + self.step_linear, self.max_linear)
        elif key in ("s", "down"):
            self.vx = clamp(self.vx - self.step_linear, self.max_linear)
        elif key in ("a", "left"):
            self.wz = clamp(self.wz + self.step_angular, self.max_angular)
        elif key in ("d", "right"):
            self.wz = clamp(self.wz - self.step_angular, self.max_angular)
        elif key == "q":
            self.vy = clamp(self.vy + self.step_linear, self.max_lateral)
        elif key == "e":
            self.vy = clamp(self.vy - self.step_linear, self.max_lateral)
        elif key in ("space", "x"):
            self.vx = self.vy = self.wz = 0.0
        else:
            return
        self.last_key_t = now

    def command(self, now: float) -> tuple[float, float, float]:
        if now - self.last_key_t > self.hold_s:
            self.vx = self.vy = self.wz = 0.0
        return self.vx, self.vy, self.wz


class KeyboardSettings(NodeSettings):
    SERVICE: ClassVar[str] = "keyboard"

    rate_hz: float = Field(default=20.0, gt=0)
    """cmd/ref rate."""
    step_linear: float = Field(default=0.05, gt=0)
    """Forward (or lateral) speed change (m/s) per key press."""
    step_angular: float = Field(default=0.2, gt=0)
    """Yaw rate change (rad/s) per key press."""
    max_linear: float = Field(default=0.5, gt=0)
    """Largest forward speed (m/s)."""
    max_lateral: float = Field(default=0.3, gt=0)
    """Largest lateral speed (m/s), mecanum."""
    max_angular: float = Field(default=1.0, gt=0)
    """Largest yaw rate (rad/s)."""
    hold_s: float = Field(default=1.0, gt=0)
    """No key for this long: the command falls back to zero (a terminal reports no key releases)."""
    source_name: str = "keyboard"
    """The source name its commands carry (VelocityCommand.source)."""


class KeyboardNode:
    def __init__(self, node: Node, s: KeyboardSettings, stdin: int | None = None):
        self.node, self.s = node, s
        self.ref_key = node.keys.cmd_ref_of(s.source_name)  # its own key: protocol.keys.REF_SOURCES
        self.core = KeyboardTeleop(s.step_linear, s.step_angular, s.max_linear, s.max_lateral, s.max_angular, s.hold_s)
        self.fd = sys.stdin.fileno() if stdin is None else stdin
        self._saved = None
        if os.isatty(self.fd):
            self._saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)
            print("keyboard teleop: w/s ↑/↓ speed, a/d ←/→ turn, q/e strafe, space stop, Ctrl-C quit",
                  file=sys.stderr, flush=True)
        node.every(1.0 / s.rate_hz, self.tick)

    def tick(self) -> None:
        now = time.monotonic()
        ready, _, _ = select.select([self.fd], [], [], 0)
        if ready:
            data = os.read(self.fd, 64)
            if not data:  # stdin closed: keep publishing zero via the hold timeout
                self.core.last_key_t = -math.inf
            for key in parse_keys(data):
                self.core.on_key(key, now)
        vx, vy, wz = self.core.command(now)
        self.node.publish(self.ref_key, VelocityCommand(
            linear=(vx, vy, 0.0), angular=(0.0, 0.0, wz), source=self.s.source_name))
        if self._saved is not None:
            print(f"\rvx {vx:+.2f} m/s  vy {vy:+.2f} m/s  wz {wz:+.2f} rad/s   ", end="", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._saved is not None:
            with contextlib.suppress(termios.error):
                termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            print(file=sys.stderr)


def setup(node: Node, s: KeyboardSettings) -> KeyboardNode:
    return KeyboardNode(node, s)


SERVICE = ServiceSpec("keyboard", KeyboardSettings, setup)


def main(argv: list[str] | None = None) -> int:
    """``python -m riskfield.edge.joystick.keyboard [-e ENDPOINT] [--robot ID] [key=value ...]``."""
    import argparse

    from riskfield.services.runtime import build_settings, parse_overrides
    from riskfield.services.runtime.session import add_connect_argument

    ap = argparse.ArgumentParser(description="Keyboard teleop: publishes cmd/ref.")
    add_connect_argument(ap)
    ap.add_argument("--robot")
    ap.add_argument("--duration", type=float)
    ap.add_argument("set", nargs="*", help="settings as key=value")
    args = ap.parse_args(argv)
    overrides = parse_overrides(args.set)
    overrides.update({k: v for k, v in (("connect", args.connect), ("robot", args.robot)) if v})
    settings = build_settings(SERVICE, overrides)
    node = Node(SERVICE.name, settings)
    handle = setup(node, settings)
    try:
        return node.run(args.duration)
    finally:
        handle.close()


if __name__ == "__main__":
    sys.exit(main())
