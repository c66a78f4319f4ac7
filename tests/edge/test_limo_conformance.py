"""The LIMO bridge's frames and state against AgileX's own computations, worked by hand.

Every expected value is worked from the vendor's functions and written here as a literal:
agilexrobotics/limo_ros at 4c78efc, ``limo_base/src/limo_driver.cpp`` (``twistCmdCallback``,
``convertCentralAngleToInner``, ``convertInnerAngleToCentral``, ``setMotionCommand``,
``parseFrame``, ``publishOdometry``, ``enableCommandedMode``, ``enableMcMode``) and pylimo 0.3.5
``pylimo/limo.py`` (``LIMO.__init__``: ``max_inner_angle = 0.48869``), with L = 0.2 m, T = 0.172 m.
The vendor's int16 cast truncates towards zero (``int16_t steering_cmd = steering_angle * 1000``);
the examples are chosen where that and rounding agree, except the steering field, which the bridge
truncates as the vendor does.

Where a plausible encoding differs from the vendor's (the central angle itself as the steering
field, clamped to 0.488; the 0x221 angular field as the yaw rate; one enable frame for every mode),
the docstring says what that encoding gives.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest

from riskfield.edge.limo import protocol as p
from riskfield.edge.limo.bridge import BridgeConfig, LimoBridge
from riskfield.edge.limo.emulator import ChassisEmulator, ChassisModel
from riskfield.edge.limo.kinematics import LimoLimits, MotionMode
from riskfield.edge.limo.serial_link import SerialLink
from riskfield.testing import wait_until

ENABLE = bytes.fromhex("550e0421" "0100000000000000" "00" "01")
ENABLE_MECANUM = bytes.fromhex("550e0421" "0100010000000000" "00" "02")


def frames(data: bytes) -> list:
    return [p.decode(f) for f in p.FrameParser().feed(data)]


def bridge(mode: MotionMode | None, **kw: object) -> LimoBridge:
    b = LimoBridge(BridgeConfig(motion_mode=mode, enable_retry_s=100, **kw))
    b.on_connected(0.0)
    return b


# -- differential ---------------------------------------------------------------------------------


def test_differential_frame_is_the_vendors() -> None:
    """``twistCmdCallback`` MODE_FOUR_DIFF: ``setMotionCommand(v, ω, 0, 0)``. v = 0.3, ω = 0.5:
    linear 300 = 0x012C, angular 500 = 0x01F4, checksum 0x01 + 0x2C + 0x01 + 0xF4 = 0x122 → 0x22."""
    b = bridge(MotionMode.DIFFERENTIAL)
    assert b.on_command(0.3, 0.0, 0.5, 0.0) == bytes.fromhex("550e0111" "012c01f400000000" "00" "22")
    # The lateral request is dropped: a skid-steer chassis cannot slide.
    assert b.on_command(0.3, 0.2, 0.5, 0.0) == bytes.fromhex("550e0111" "012c01f400000000" "00" "22")


def test_the_enable_frame_is_the_vendors_for_every_mode_but_mecanum() -> None:
    """``enableCommandedMode``: {1, 0, 0, 0, 0, 0, 0, 0}, checksum 1."""
    for mode in (None, MotionMode.DIFFERENTIAL, MotionMode.ACKERMANN):
        assert LimoBridge(BridgeConfig(motion_mode=mode)).on_connected(0.0)[:14] == ENABLE


# -- Ackermann -------------------------------------------------------------------------------------


def test_ackermann_frame_is_the_inner_angle_over_1_64() -> None:
    """v = 0.5, ω = 0.5: r = v/ω = 1 m; central c = atan(L/r) = 0.197396; inner
    tan i = 2L·sin c / (2L·cos c − T·sin c) = L / (r − T/2) = 0.2 / 0.914 → i = 0.215423 (below
    0.48869); field i / 1.64 = 0.131355 → 131 = 0x0083; linear 500 = 0x01F4, angular 0.
    Checksum 0x01 + 0xF4 + 0x83 = 0x178 → 0x78. The field is not c itself (197 = 0x00C5)."""
    b = bridge(MotionMode.ACKERMANN)
    assert b.on_command(0.5, 0.0, 0.5, 0.0) == bytes.fromhex("550e0111" "01f4000000000083" "00" "78")


def test_ackermann_reversing_keeps_the_vendors_sign() -> None:
    """v = −0.3, ω = 0.3: r = −1 m, c = atan(L/r) = −0.197396, i = −0.215423, field −0.131355 →
    −131 (towards zero) = 0xFF7D; linear −300 = 0xFED4. Checksum 0xFE+0xD4+0xFF+0x7D = 0x24E → 0x4E.
    Not −197."""
    b = bridge(MotionMode.ACKERMANN)
    assert b.on_command(-0.3, 0.0, 0.3, 0.0) == bytes.fromhex("550e0111" "fed400000000ff7d" "00" "4e")


def test_ackermann_clamps_the_inner_wheel() -> None:
    """v = 0.2, ω = 3: r = 0.0667 < T/2, so the vendor takes r = T/2 + 0.01 = 0.096; c = atan(0.2/0.096)
    = 1.123276; 2L·cos c − T·sin c = 0.018030 > 0, i = atan(0.4·sin c / 0.018030) = 1.520838,
    clamped to pylimo's 0.48869 → field 0.297982 → 297 = 0x0129 (the bridge's 0.488, the
    reference's figure, gives 0.297561 → 297 too: the same frame). Linear 200 = 0x00C8.
    Checksum 0xC8 + 0x01 + 0x29 = 0xF2. Not 488 (the central angle clamped to 0.488).
    (limo_ros at HEAD compares i with 28.0 and would send 1.520838 / 1.64 → 927.)"""
    b = bridge(MotionMode.ACKERMANN)
    assert b.on_command(0.2, 0.0, 3.0, 0.0) == bytes.fromhex("550e0111" "00c8000000000129" "00" "f2")
    assert b.on_command(0.2, 0.0, -3.0, 0.0)[10:12] == (-297).to_bytes(2, "big", signed=True)


def test_the_central_limit_follows_from_the_inner_one_and_the_geometry() -> None:
    """``convertInnerAngleToCentral`` at the limit: r = L / tan i + T/2, c = atan(L / r).
    i = 0.488: tan i = 0.530674, r = 0.376878 + 0.086 = 0.462774 m, c = atan(0.432176) = 0.407933.
    i = 0.48869 (pylimo): r = 0.462147 m, c = 0.408427. 0.488 is the inner wheel's limit: as the
    central one it would allow a radius of L / tan 0.488 = 0.378 m."""
    lim = LimoLimits()
    assert lim.max_central_steering == pytest.approx(0.407933, abs=1e-6)
    assert 1 / lim.max_curvature == pytest.approx(0.462774, abs=1e-6)
    vendor = LimoLimits(max_steering=0.48869)
    assert vendor.max_central_steering == pytest.approx(0.408427, abs=1e-6)
    assert 1 / vendor.max_curvature == pytest.approx(0.462147, abs=1e-6)
    # Derived, not typed: another track gives another central limit.
    assert LimoLimits(track=0.2).max_central_steering < lim.max_central_steering


@pytest.mark.parametrize(("raw", "linear", "wz", "central"), [
    # s = 0.1 > 0: i = 0.1 × 2.47 = 0.247; tan i = 0.252149, r = 0.2/0.252149 + 0.086 = 0.879183;
    # ω = v / r = 0.568710, c = atan(0.2 / 0.879183) = 0.223678.
    (100, 0.5, 0.568710, 0.223678),
    # s = −0.1: i = −0.1 × 1.64 = −0.164; tan 0.164 = 0.165486, r = 1.208559 + 0.086 = 1.294559;
    # ω = −v / r = −0.386232, c = −atan(0.2 / 1.294559) = −0.153281.
    (-100, 0.5, -0.386232, -0.153281),
    # Backing up with the wheels left: ω = v / r with v < 0, the vendor's sign.
    (100, -0.5, -0.568710, 0.223678),
])
def test_ackermann_state_from_the_steering_feedback(raw: int, linear: float, wz: float, central: float) -> None:
    """``parseFrame`` (0x221: s = raw / 1000, ×2.47 if s > 0 else ×1.64 is the inner angle) and
    ``publishOdometry`` MODE_ACKERMANN (r = L / tan|i| + T/2, ω = ±v / r by the sign of the central
    angle). The frame's angular field is 0, as the vendor ignores it; ω does not come from it."""
    b = bridge(MotionMode.ACKERMANN, use_imu=False)
    data = (round(linear * 1e3).to_bytes(2, "big", signed=True) + bytes(4) + raw.to_bytes(2, "big", signed=True))
    b.on_bytes(p.encode_frame(p.MOTION_STATE_ID, data) + p.encode(p.Odometry(0.0, 0.0)), 1.0)
    s = b.state(1.0)
    assert s is not None
    assert s.wz == pytest.approx(wz, abs=1e-6)
    assert (s.vx, s.vy) == (linear, 0.0)
    assert s.steering == pytest.approx(central, abs=1e-6)


# -- mecanum -----------------------------------------------------------------------------------------


def test_mecanum_forces_the_mode_frame_and_sends_lateral_whatever_d6_says() -> None:
    """``use_mcnamu``: the constructor sends ``enableCommandedMode`` then ``enableMcMode``,
    {1, 0, 1, 0, 0, 0, 0, 0} (checksum 2), and ``parseFrame`` ignores 0x211 d6. MODE_MCNAMU:
    ``setMotionCommand(v, ω, vy, 0)``; v = 0.2, vy = 0.1, ω = 0.3 → 200 = 0x00C8, 300 = 0x012C,
    100 = 0x0064; checksum 0xC8 + 0x01 + 0x2C + 0x64 = 0x159 → 0x59. Not the plain enable
    frame, and a chassis reporting d6 = 0 (it cannot see its mecanum wheels) is no mode mismatch."""
    b = LimoBridge(BridgeConfig(motion_mode=MotionMode.MECANUM, enable_retry_s=1.0))
    assert b.on_connected(0.0)[:14] == ENABLE_MECANUM
    assert b.tick(1.5)[:14] == ENABLE_MECANUM  # the retries too, until the chassis confirms
    b.on_bytes(p.encode(p.SystemState(control_mode=1, motion_mode=0)), 1.6)
    assert b.mode == MotionMode.MECANUM and not b.diag.mode_mismatch
    assert b.on_command(0.2, 0.1, 0.3, 2.0) == bytes.fromhex("550e0111" "00c8012c00640000" "00" "59")
    b.on_bytes(p.encode(p.SystemState(control_mode=1, motion_mode=1)), 2.1)
    assert b.diag.mode_mismatch  # the Ackermann latch contradicts mecanum wheels


def test_auto_mode_sends_lateral_when_the_chassis_reports_mecanum() -> None:
    b = bridge(None)
    assert b.on_command(0.2, 0.1, 0.3, 0.0)[8:10] == bytes(2)  # differential until the chassis says
    b.on_bytes(p.encode(p.SystemState(control_mode=1, motion_mode=2)), 0.1)
    assert b.on_command(0.2, 0.1, 0.3, 0.2) == bytes.fromhex("550e0111" "00c8012c00640000" "00" "59")


# -- end to end over the pty emulator ------------------------------------------------------------


def drive(emu: ChassisEmulator, b: LimoBridge, commands: list[tuple[float, float, float]],
          until: object) -> SerialLink:
    link = SerialLink(emu.port, 460800)
    assert link.try_open(time.monotonic())
    link.write(b.on_connected(time.monotonic()))

    def step() -> bool:
        now = time.monotonic()
        for vx, vy, wz in commands:
            link.write(b.on_command(vx, vy, wz, now))
        b.on_bytes(link.read(), now)
        return until()  # type: ignore[operator]

    assert wait_until(step, 5.0, period_s=0.01)
    return link


def test_ackermann_end_to_end_drives_the_commanded_circle(tmp_path: Path) -> None:
    """v = 0.3, ω = 0.3 (r = 1 m) through the bridge, the pty and the emulated chassis, which reads
    the field as the vendor's chassis does (×1.64 → inner → central): it turns at ω ≈ 0.3 and the
    bridge's state, from the steering feedback, agrees. The central angle as the field, 197, reads
    as an inner angle of 0.323 and gives ω = 0.439."""
    model = ChassisModel(motion_mode=MotionMode.ACKERMANN)
    with ChassisEmulator(model, link=str(tmp_path / "limo")) as emu:
        b = LimoBridge(BridgeConfig(motion_mode=MotionMode.ACKERMANN, watchdog_s=10, use_imu=False))
        link = drive(emu, b, [(0.3, 0.0, 0.3)], lambda: (s := b.state(time.monotonic())) is not None
                     and s.x > 0.05 and emu.model.v == 0.3)
        try:
            assert emu.model.w == pytest.approx(0.3, abs=0.003)  # the field's 0.001 step
            s = b.state(time.monotonic())
            assert s is not None and s.wz == pytest.approx(emu.model.w, abs=1e-3)
            assert s.steering == pytest.approx(math.atan(0.3 * 0.2 / 0.3), abs=3e-3)
        finally:
            link.write(b.shutdown())
            link.close()


def test_ackermann_end_to_end_beyond_the_limit_follows_the_tightest_circle(tmp_path: Path) -> None:
    """ω = 3 at v = 0.2 asks for r = 0.067 m: the chassis turns on the 0.46 m circle (ω = 0.2 / 0.4628
    = 0.432), and the wheel reaches its limit. The clamped central angle as the field, 488, reads as
    0.80 rad of inner angle, which the chassis clamps at 0.488: the same circle only by the mechanical stop."""
    model = ChassisModel(motion_mode=MotionMode.ACKERMANN)
    with ChassisEmulator(model, link=str(tmp_path / "limo")) as emu:
        b = LimoBridge(BridgeConfig(motion_mode=MotionMode.ACKERMANN, watchdog_s=10, use_imu=False))
        link = drive(emu, b, [(0.2, 0.0, 3.0)], lambda: emu.model.v == 0.2)
        try:
            assert emu.model.w == pytest.approx(0.2 / 0.462774, abs=0.003)
            assert emu.model.inner <= LimoLimits().max_steering
            assert emu.model.inner == pytest.approx(0.297 * 1.64)
        finally:
            link.close()


def test_mecanum_end_to_end_switches_the_chassis_and_slides(tmp_path: Path) -> None:
    """A chassis in differential mode with mecanum wheels (d6 keeps saying 0): the bridge's mecanum
    frame switches it and the lateral speed reaches it; the plain enable frame neither switches nor slides it."""
    model = ChassisModel(motion_mode=MotionMode.DIFFERENTIAL, reported_mode=0)
    with ChassisEmulator(model, link=str(tmp_path / "limo")) as emu:
        b = LimoBridge(BridgeConfig(motion_mode=MotionMode.MECANUM, watchdog_s=10))
        link = drive(emu, b, [(0.0, 0.2, 0.0)], lambda: emu.model.y > 0.02)
        try:
            assert any(m == p.ControlModeCommand(enable=True, mecanum=True) for _, m in emu.frames())
            assert emu.model.motion_mode == MotionMode.MECANUM and emu.model.vy == 0.2
            assert not b.diag.mode_mismatch and b.diag.motion_mode == 0
        finally:
            link.close()
