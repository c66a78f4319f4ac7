"""The LIMO bridge's command watchdog thread: a stop frame reaches the chassis while the node's loop is stuck."""

from __future__ import annotations

import os
import threading
import uuid
from pathlib import Path

import pytest

from riskfield.edge.limo import protocol as p
from riskfield.edge.limo.emulator import ChassisEmulator
from riskfield.edge.limo.node import LimoNode, LimoSettings
from riskfield.edge.limo.watchdog import CommandWatchdog
from riskfield.protocol import Keys, VelocityCommand
from riskfield.services.runtime import Node
from riskfield.testing import client_session, put, wait_alive, wait_until

STOP = p.encode(p.MotionCommand())


def drain(fd: int) -> bytes:
    out = b""
    while True:
        try:
            chunk = os.read(fd, 4096)
        except BlockingIOError:
            return out
        if not chunk:
            return out
        out += chunk


@pytest.fixture
def pipe():
    r, w = os.pipe()
    os.set_blocking(r, False)
    yield r, w
    for fd in (r, w):
        try:
            os.close(fd)
        except OSError:
            pass


def test_stops_after_the_timeout_repeats_and_settles(pipe: tuple[int, int]) -> None:
    r, w = pipe
    wd = CommandWatchdog(timeout_s=0.2, repeat_s=0.1)
    wd.attach(w)
    try:
        assert not wd.check(10.0)  # nothing commanded yet
        wd.commanded(True, 10.0)
        assert not wd.check(10.2) and drain(r) == b""  # still fresh (the bound is "older than")
        assert wd.check(10.21) and drain(r) == STOP
        assert not wd.check(10.25)  # repeats wait for repeat_s
        assert wd.check(10.32) and drain(r) == STOP
        assert (wd.fired, wd.frames) == (1, 2)
        wd.settled()  # the loop wrote its own stop: nothing left to cover
        assert not wd.check(11.0) and drain(r) == b""
        wd.commanded(True, 12.0)
        wd.commanded(False, 12.05)  # a zero command is a stop: nothing to time out
        assert not wd.check(13.0)
        wd.commanded(True, 14.0)
        assert wd.check(14.3) and wd.fired == 2
    finally:
        wd.detach()


def test_writes_nothing_without_a_port_and_counts_refused_writes(pipe: tuple[int, int]) -> None:
    r, w = pipe
    wd = CommandWatchdog(timeout_s=0.2, repeat_s=0.1)
    wd.commanded(True, 0.0)
    assert not wd.check(1.0)  # never attached
    wd.attach(w)
    wd.detach()
    assert not wd.check(1.1) and drain(r) == b""
    os.close(r)  # the other end is gone: the write fails, is counted, and is tried again
    wd.attach(w)
    try:
        assert not wd.check(1.2) and wd.write_errors == 1
        assert not wd.check(1.3) and wd.write_errors == 2 and wd.fired == 0
    finally:
        wd.detach()


class StallingLimoNode(LimoNode):
    """The real node, whose command handler blocks the loop once armed: the stand-in for a loop that
    is stuck (a handler, a timer or the runtime itself) right after it wrote a moving command."""

    def __init__(self, *args: object, **kw: object):
        self.armed = False
        self.entered = threading.Event()
        self.release = threading.Event()
        super().__init__(*args, **kw)  # type: ignore[arg-type]

    def on_command(self, cmd: VelocityCommand) -> None:
        super().on_command(cmd)
        if self.armed:
            self.armed = False
            self.entered.set()
            self.release.wait(30.0)


@pytest.mark.parametrize("timed", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_a_stuck_loop_still_stops_the_chassis(router_endpoint: str, tmp_path: Path, timed: bool) -> None:
    """The loop writes a moving command and blocks. The emulated chassis then receives a stop frame
    (and its repeat) while the loop is still blocked, so neither came from the loop's own watchdog.
    ``timed`` (slow): within ``watchdog_s`` plus the thread's period and a busy machine's margin."""
    robot = f"t_limo_wd_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    watchdog_s = 0.3
    moving_t: list[float] = []
    stop_t: list[float] = []
    second_stop = threading.Event()

    def on_frame(t: float, msg: object) -> None:  # the emulator's thread
        if not isinstance(msg, p.MotionCommand):
            return
        if not msg.is_stop:
            moving_t.append(t)
        elif moving_t:
            stop_t.append(t)
            if len(stop_t) >= 2:
                second_stop.set()

    with ChassisEmulator(link=str(tmp_path / "limo"), on_frame=on_frame) as emu, \
            client_session(router_endpoint) as s:
        settings = LimoSettings(connect=[router_endpoint], robot=robot, port=emu.port, reconnect_s=0.1,
                                watchdog_s=watchdog_s, stop_repeat_s=0.1)
        node = Node("limo", settings)
        limo = StallingLimoNode(node, settings)
        loop = threading.Thread(target=node.run, daemon=True)
        loop.start()
        try:
            assert wait_alive(s, keys.alive("limo"))
            assert wait_until(lambda: emu.model.control_mode == 1, 5.0)
            limo.armed = True
            put(s, keys.cmd_safe, VelocityCommand(linear=(0.3, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="test"))
            assert limo.entered.wait(5.0)
            assert second_stop.wait(5.0), (moving_t, stop_t, limo.watchdog.__dict__)
            assert not limo.release.is_set() and loop.is_alive()  # the loop is still stuck in the handler
            assert limo.core.diag.watchdog_stops == 0  # its own watchdog never ran
            # the chassis may parse the repeat before the thread, back from its write, counts it
            assert wait_until(lambda: limo.watchdog.frames >= 2, 5.0) and limo.watchdog.fired == 1
            assert emu.model.v == 0.0
            latency = stop_t[0] - moving_t[-1]
            assert latency >= watchdog_s - 0.02, latency  # not before the timeout
            if timed:
                assert latency <= watchdog_s + limo.watchdog.check_s + 0.1, latency
            print(f"\nwatchdog thread stop {1e3 * latency:.0f} ms after the last command (watchdog_s "
                  f"{1e3 * watchdog_s:.0f} ms)")
            # Released, the loop's own watchdog stops as well and the thread leaves the repeats to it.
            limo.release.set()
            assert wait_until(lambda: limo.core.diag.watchdog_stops == 1 and not limo.watchdog._moving, 5.0)
        finally:
            limo.release.set()
            node.stop()
            loop.join(10.0)
            limo.close()
