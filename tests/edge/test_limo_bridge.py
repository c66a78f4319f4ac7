"""The LIMO bridge core: command mode, watchdog, limits, feedback → state (no I/O)."""

from __future__ import annotations

import math

import pytest

from riskfield.edge.limo import protocol as p
from riskfield.edge.limo.bridge import BridgeConfig, LimoBridge
from riskfield.edge.limo.emulator import ChassisModel
from riskfield.edge.limo.kinematics import MotionMode


def frames(data: bytes) -> list:
    return [p.decode(f) for f in p.FrameParser().feed(data)]


def connected(config: BridgeConfig | None = None) -> LimoBridge:
    b = LimoBridge(config)
    out = frames(b.on_connected(0.0))
    assert out == [p.ControlModeCommand(enable=True), p.MotionCommand()]
    return b


def test_connect_enables_command_mode_and_stops() -> None:
    b = connected()
    assert b.on_connected(0.1) == b""  # already connected: nothing twice


def test_enable_is_retried_until_the_chassis_confirms() -> None:
    b = connected(BridgeConfig(enable_retry_s=1.0))
    assert p.ControlModeCommand(enable=True) not in frames(b.tick(0.5))
    assert p.ControlModeCommand(enable=True) in frames(b.tick(1.01))
    b.on_bytes(p.encode(p.SystemState(control_mode=1)), 1.1)
    assert b.diag.command_mode_confirmed
    assert p.ControlModeCommand(enable=True) not in frames(b.tick(5.0))


def test_watchdog_stops_once_then_repeats_stop_frames() -> None:
    b = connected(BridgeConfig(watchdog_s=0.2, stop_repeat_s=0.1, enable_retry_s=100))
    (m,) = frames(b.on_command(0.4, 0.0, 0.2, 1.0))
    assert m == p.MotionCommand(0.4, 0.2, 0.0, 0.0)
    assert frames(b.tick(1.15)) == []  # command still fresh
    assert frames(b.tick(1.21)) == [p.MotionCommand()]
    assert b.diag.watchdog_stops == 1
    assert frames(b.tick(1.25)) == []
    assert frames(b.tick(1.32)) == [p.MotionCommand()]  # repeated: a lost stop frame must not matter
    assert b.diag.watchdog_stops == 1


def test_commands_are_clamped() -> None:
    b = connected()
    (m,) = frames(b.on_command(3.0, 0.0, 0.0, 0.0))
    assert m.linear == pytest.approx(1.0)


def test_shutdown_is_a_stop_frame() -> None:
    b = connected()
    b.on_command(0.5, 0.0, 0.0, 0.0)
    assert frames(b.shutdown()) == [p.MotionCommand()]


def test_auto_mode_follows_the_chassis_report() -> None:
    b = connected()
    assert b.mode == MotionMode.DIFFERENTIAL
    b.on_bytes(p.encode(p.SystemState(motion_mode=1)), 0.0)
    assert b.mode == MotionMode.ACKERMANN
    (m,) = frames(b.on_command(0.5, 0.0, 0.5, 0.0))
    assert m.steering != 0.0 and m.angular == 0.0


def test_configured_mode_mismatch_is_reported() -> None:
    b = connected(BridgeConfig(motion_mode=MotionMode.DIFFERENTIAL))
    b.on_bytes(p.encode(p.SystemState(motion_mode=2)), 0.0)
    assert b.diag.mode_mismatch and b.mode == MotionMode.DIFFERENTIAL


def test_state_from_emulated_feedback_follows_the_chassis() -> None:
    """Drive the pure chassis model with the bridge's frames; the estimate tracks its pose."""
    model = ChassisModel(yaw_offset=0.7)
    b = LimoBridge(BridgeConfig(enable_retry_s=100, watchdog_s=10))
    for msg in frames(b.on_connected(0.0)):
        model.apply(msg)
    t, dt = 0.0, 0.02
    b.on_bytes(model.feedback(), t)
    for msg in frames(b.on_command(0.5, 0.0, 0.4, t)):
        model.apply(msg)
    for _ in range(150):
        t += dt
        model.step(dt)
        b.on_bytes(model.feedback(), t)
    s = b.state(t)
    assert s is not None
    assert (s.x, s.y) == pytest.approx((model.x, model.y), abs=0.02)
    assert s.yaw == pytest.approx(model.yaw, abs=0.01)
    assert (s.vx, s.wz) == pytest.approx((0.5, 0.4), abs=1e-3)
    vx, vy = s.world_velocity()
    assert math.hypot(vx, vy) == pytest.approx(0.5, abs=1e-3)
    assert b.diag.frames_bad == 0 and b.diag.frames_ok > 0
    assert b.diag.battery_v == pytest.approx(12.1)


def test_state_goes_stale_without_feedback() -> None:
    b = connected(BridgeConfig(feedback_timeout_s=0.5))
    b.on_bytes(p.encode(p.Odometry(0, 0)), 1.0)
    assert b.state(1.2) is not None
    assert b.state(1.6) is None


def test_corrupt_bytes_are_counted_and_skipped() -> None:
    b = connected()
    bad = bytearray(p.encode(p.Odometry(1.0, 1.0)))
    bad[6] ^= 0xFF
    b.on_bytes(b"\x01\x02\x55" + bytes(bad) + p.encode(p.SystemState(battery_v=11.5)), 0.0)
    assert b.diag.frames_bad == 1 and b.diag.bytes_skipped >= 3
    assert b.diag.battery_v == pytest.approx(11.5)


def test_disconnect_counts_a_reconnect_and_resets_the_odometry_reference() -> None:
    b = connected()
    b.on_bytes(p.encode(p.Odometry(1.0, 1.0)), 0.0)
    b.on_bytes(p.encode(p.Odometry(1.1, 1.1)), 0.02)
    b.on_disconnected()
    assert b.diag.reconnects == 1 and not b.diag.connected
    assert b.tick(1.0) == b""  # nothing to write while there is no port
    b.on_connected(2.0)
    b.on_bytes(p.encode(p.Odometry(0.0, 0.0)), 2.0)  # the chassis restarted its counters
    b.on_bytes(p.encode(p.Odometry(0.05, 0.05)), 2.02)
    s = b.state(2.02)
    assert s is not None and s.x == pytest.approx(0.15)


@pytest.mark.parametrize("mode", list(MotionMode))
def test_dry_run_writes_stops_for_every_mode_and_counts_only_what_would_have_moved(mode: MotionMode) -> None:
    b = LimoBridge(BridgeConfig(dry_run=True, motion_mode=mode))
    assert frames(b.on_connected(0.0))[-1] == p.MotionCommand()  # the enable frame goes out as usual
    for i, (vx, vy, wz) in enumerate([(0.4, 0.1, 0.3), (-0.2, 0.0, 0.0), (0.0, 0.3, 0.0), (0.0, 0.0, 0.0)]):
        assert frames(b.on_command(vx, vy, wz, 0.01 * i)) == [p.MotionCommand()]
    moving = 2 + (mode == MotionMode.MECANUM)  # only mecanum moves sideways; zero is nothing to withhold
    assert (b.diag.commands, b.diag.withheld_commands) == (4, moving)
    assert b.stopped and b.withheld is not None and not b.withheld.is_stop
    live = LimoBridge(BridgeConfig(motion_mode=mode))
    live.on_connected(0.0)
    assert not p.decode(p.FrameParser().feed(live.on_command(0.4, 0.1, 0.3, 0.0))[0]).is_stop
    assert live.diag.withheld_commands == 0
