"""Keyboard teleop: key parsing, the step/hold logic, and the node on a real pty as its terminal."""

from __future__ import annotations

import os
import subprocess
import sys
import uuid

import pytest

from riskfield.edge.joystick.keyboard import KeyboardTeleop, parse_keys
from riskfield.protocol import Keys, VelocityCommand
from riskfield.testing import Collector, client_session, wait_alive, wait_until


def test_parse_keys_with_arrow_escapes() -> None:
    assert parse_keys(b"wW \x1b[A\x1b[Dx\x1bOC") == ["w", "w", "space", "up", "left", "x", "right"]


def test_steps_limits_stop_and_hold_timeout() -> None:
    k = KeyboardTeleop(step_linear=0.1, max_linear=0.25, hold_s=1.0)
    for _ in range(5):
        k.on_key("w", 0.0)
    assert k.command(0.1) == pytest.approx((0.25, 0.0, 0.0))
    k.on_key("left", 0.2)
    assert k.command(0.3)[2] == pytest.approx(k.step_angular)
    k.on_key("space", 0.4)
    assert k.command(0.5) == (0.0, 0.0, 0.0)
    k.on_key("s", 1.0)
    assert k.command(1.5)[0] == pytest.approx(-0.1)
    assert k.command(2.1) == (0.0, 0.0, 0.0)  # no key for hold_s: released
    k.on_key("?", 2.2)  # unknown keys do not count as "still there"
    assert k.command(3.3) == (0.0, 0.0, 0.0)


def test_keyboard_node_on_a_pty(router_endpoint: str) -> None:
    robot = f"t_kb_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    master, slave = os.openpty()
    with client_session(router_endpoint) as s:
        refs = Collector(s, keys.cmd_ref_of("keyboard"), VelocityCommand)
        proc = subprocess.Popen(
            [sys.executable, "-m", "riskfield.edge.joystick.keyboard", "-e", router_endpoint, "--robot", robot,
             "hold_s=0.5", "rate_hz=20"],
            stdin=slave, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            assert wait_alive(s, keys.alive("keyboard"))
            os.write(master, b"ww\x1b[A")
            assert wait_until(lambda: any(m.linear[0] == pytest.approx(0.15) for m in refs.items), 3.0)
            # No key held any more: after hold_s the command returns to zero by itself.
            assert wait_until(lambda: refs.items[-1].linear[0] == 0.0, 5.0)
            assert refs.items[-1].source == "keyboard"
        finally:
            proc.send_signal(2)
            _, err = proc.communicate(timeout=10)
            os.close(master)
            os.close(slave)
            refs.close()
        assert proc.returncode == 0, err.decode()
