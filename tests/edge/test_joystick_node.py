"""The ``joystick`` node in its own process: recorded sessions (loss, reconnect) and raw events."""

from __future__ import annotations

import json
import os
import uuid
from pathlib import Path

import pytest

from riskfield.edge.joystick.mapping import CODES, EV_ABS, EV_KEY, EV_SYN, SYN_REPORT
from riskfield.edge.joystick.source import pack_event, packets
from riskfield.protocol import Keys, VelocityCommand
from riskfield.testing import Collector, ServiceProcess, client_session, wait_alive, wait_until

Y, RZ, THR, TRIG = (CODES[n] for n in ("ABS_Y", "ABS_RZ", "ABS_THROTTLE", "BTN_TRIGGER"))


def test_recorded_joystick_publishes_zero_on_release_and_loss(
        router_endpoint: str, tmp_path: Path) -> None:
    robot = f"t_js_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    rec = tmp_path / "session.json"
    rec.write_text(json.dumps({"sessions": [
        {"events": packets((1.5, [(EV_KEY, TRIG, 1), (EV_ABS, Y, 0)]), (2.0, [(EV_KEY, TRIG, 0)])),
         "axes": {str(THR): 0, str(Y): 511}, "lost_at": 2.5},
        {"events": packets((0.3, [(EV_KEY, TRIG, 1), (EV_ABS, RZ, 0)])), "axes": {str(THR): 0}},
    ]}))
    with client_session(router_endpoint) as s:
        refs = Collector(s, keys.cmd_ref_of("joystick"), VelocityCommand)
        args = ["--robot", robot, "--set", "source=recorded", "--set", f"device={rec}", "--set", "rate_hz=20",
                "--set", "reconnect_s=0.5", "--set", "max_linear=0.4"]
        with ServiceProcess("joystick", router_endpoint, args) as node:
            assert wait_alive(s, keys.alive("joystick")), node.output
            assert wait_until(lambda: any(m.angular[2] > 0 for m in refs.items), 10.0), node.output
            msgs = list(refs.items)
            assert node.stop() == 0
            output = node.output
        refs.close()
    vx = [m.linear[0] for m in msgs]
    assert vx[0] == 0.0  # zero until the dead-man is pressed
    assert max(vx) == pytest.approx(0.4)  # stick forward, slider at "+"
    first_drive = vx.index(max(vx))
    after = vx[first_drive:]
    assert 0.0 in after  # released → zero
    i_zero = first_drive + after.index(0.0)
    assert all(v == 0.0 for v in vx[i_zero:])  # loss and the second session keep vx at zero
    assert msgs[-1].angular[2] == pytest.approx(1.0) and msgs[-1].source == "joystick"
    assert "joystick lost" in output and output.count("open (") == 2  # lost once, reopened


def test_raw_event_fifo_drives_the_node(router_endpoint: str, tmp_path: Path) -> None:
    robot = f"t_js_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    fifo = tmp_path / "event0"
    os.mkfifo(fifo)
    with client_session(router_endpoint) as s:
        refs = Collector(s, keys.cmd_ref_of("joystick"), VelocityCommand)
        # Neither the poll (every 600 s) nor the fixed-rate publication (every 1000 s) comes due
        # during the test: only the descriptor wake-up can deliver an event at all.
        args = ["--robot", robot, "--set", "source=raw", "--set", f"device={fifo}", "--set", "speed_scale=",
                "--set", "rate_hz=0.001", "--set", "poll_s=600"]
        with ServiceProcess("joystick", router_endpoint, args) as node:
            assert wait_alive(s, keys.alive("joystick")), node.output
            w = os.open(fifo, os.O_WRONLY)
            try:
                # Garbage-free but odd input: unknown codes and a lone SYN are ignored.
                os.write(w, pack_event(EV_ABS, 0x28, 5) + pack_event(EV_SYN, SYN_REPORT, 0))
                os.write(w, pack_event(EV_KEY, TRIG, 1) + pack_event(EV_ABS, Y, 1023)
                         + pack_event(EV_SYN, SYN_REPORT, 0))
                # A change is published at once, not at the next tick.
                assert wait_until(lambda: any(m.linear[0] < 0 for m in refs.items), 10.0), node.output
                assert refs.items[-1].linear[0] == pytest.approx(-0.5)  # stick back, no speed scale
            finally:
                os.close(w)
            # A new writer after the first left (the FIFO hung up in between) is heard just as fast.
            w = os.open(fifo, os.O_WRONLY)
            try:
                os.write(w, pack_event(EV_ABS, Y, 0) + pack_event(EV_SYN, SYN_REPORT, 0))
                assert wait_until(lambda: refs.items[-1].linear[0] > 0, 10.0), node.output
            finally:
                os.close(w)
            assert node.stop() == 0
        refs.close()
