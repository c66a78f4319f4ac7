"""The serial link and the chassis emulator over a real pseudo-terminal (no Zenoh)."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from riskfield.edge.limo import protocol as p
from riskfield.edge.limo.bridge import BridgeConfig, LimoBridge
from riskfield.edge.limo.emulator import ChassisEmulator
from riskfield.edge.limo.serial_link import SerialLink
from riskfield.testing import wait_until


def pump_until(link: SerialLink, bridge: LimoBridge, predicate: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    """Feed the chassis' bytes to the bridge until ``predicate`` holds (False on a lost link or timeout)."""

    def step() -> bool:
        try:
            bridge.on_bytes(link.read(), time.monotonic())
        except ConnectionError:
            bridge.on_disconnected()
            raise
        return predicate()

    return wait_until(step, timeout_s, period_s=0.005)


def test_bridge_drives_the_emulated_chassis_over_a_pty(tmp_path: Path) -> None:
    with ChassisEmulator(link=str(tmp_path / "limo")) as emu:
        link = SerialLink(emu.port, 460800)
        bridge = LimoBridge(BridgeConfig(watchdog_s=10))
        try:
            assert link.try_open(time.monotonic())
            link.write(bridge.on_connected(time.monotonic()))
            link.write(bridge.on_command(0.5, 0.0, 0.0, time.monotonic()))
            assert wait_until(lambda: any(m == p.MotionCommand(0.5) for _, m in emu.frames()), 2.0)
            assert emu.model.control_mode == 1 and emu.model.v == 0.5
            def driven() -> bool:
                s = bridge.state(time.monotonic())
                return bridge.diag.command_mode_confirmed and s is not None and s.x > 0.1

            assert pump_until(link, bridge, driven)
            s = bridge.state(time.monotonic())
            assert s is not None and s.vx == 0.5
            assert bridge.diag.frames_bad == 0
            # Noise and a corrupt frame on the line: counted, and feedback keeps coming.
            bad = bytearray(p.encode(p.Odometry(9.0, 9.0)))
            bad[13] ^= 0x55
            emu.inject(b"\xde\xad\x55" + bytes(bad))
            ok_before = bridge.diag.frames_ok
            assert pump_until(link, bridge, lambda: bridge.diag.frames_bad >= 1 and bridge.diag.frames_ok > ok_before)
            assert bridge.odometry.jumps == 0
        finally:
            link.close()


def test_link_detects_loss_and_reopens_the_repointed_path(tmp_path: Path) -> None:
    with ChassisEmulator(link=str(tmp_path / "limo")) as emu:
        link = SerialLink(emu.port, 460800, reconnect_s=0.05)
        try:
            assert link.try_open(time.monotonic())
            emu.disconnect()

            def lost() -> bool:
                try:
                    link.read()
                    link.write(p.encode(p.MotionCommand()))
                except ConnectionError:
                    return True
                return False

            assert wait_until(lost, 2.0, period_s=0.01) and not link.is_open
            assert not link.try_open(time.monotonic() + 1)  # nothing at the path yet
            emu.reconnect()
            assert Path(emu.port).resolve() == Path(emu.path)
            assert wait_until(lambda: link.try_open(time.monotonic()), 2.0)
            link.write(p.encode(p.ControlModeCommand(enable=True)))
            assert wait_until(lambda: emu.model.control_mode == 1, 2.0)
        finally:
            link.close()


def test_open_of_a_missing_port_fails_cleanly(tmp_path: Path) -> None:
    link = SerialLink(str(tmp_path / "nothing"), 460800, reconnect_s=10)
    assert not link.try_open(0.0)
    assert "cannot open" in link.last_error
    assert not link.try_open(1.0)  # retry not due yet
    assert link.read() == b""
    link.write(b"\x00")  # a write with no port is a no-op, not an exception


def test_command_logger_prints_each_move_stop_change_once(capsys) -> None:
    """``--log-commands``: one line per change between moving and stopped commands, with the time
    (the container tests find a network cut's brake by it), and nothing for other frames."""
    from riskfield.edge.limo.emulator import command_logger

    clock = iter([100.0, 101.5, 102.25])
    log = command_logger(lambda: next(clock))
    for msg in (p.MotionCommand(0.3, 0.1), p.MotionCommand(0.3, 0.0), p.ControlModeCommand(True),
                p.MotionCommand(0.0, 0.0), p.MotionCommand(0.0, 0.0), p.MotionCommand(-0.2, 0.0)):
        log(0.0, msg)
    lines = capsys.readouterr().out.splitlines()
    assert lines == ["limo-emulator: 100.000000 move v=+0.300 w=+0.100",
                     "limo-emulator: 101.500000 stop v=+0.000 w=+0.000",
                     "limo-emulator: 102.250000 move v=-0.200 w=+0.000"]
