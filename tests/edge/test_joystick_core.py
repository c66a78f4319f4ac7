"""Joystick mapping, event sources and the gateway core, driven by recorded event sequences."""

from __future__ import annotations

import os
import select
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from riskfield.edge.joystick.gateway import GatewayConfig, JoystickGateway
from riskfield.edge.joystick.mapping import (
    CODES,
    EV_ABS,
    EV_KEY,
    EV_SYN,
    SYN_DROPPED,
    SYN_REPORT,
    AxisSpec,
    JoystickMapping,
    command,
)
from riskfield.edge.joystick.source import (
    DeviceInfo,
    DeviceLost,
    DeviceUnavailable,
    RawEventSource,
    RecordedSource,
    Session,
    pack_event,
    packets,
)
from riskfield.testing import wait_until

X, Y, RZ, THR, TRIG = (CODES[n] for n in ("ABS_X", "ABS_Y", "ABS_RZ", "ABS_THROTTLE", "BTN_TRIGGER"))


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


# -- mapping ----------------------------------------------------------------------------------


def test_axis_normalisation_and_deadzone() -> None:
    a = AxisSpec(Y, 0, 1023, invert=False, deadzone=0.1)
    assert a.normalise(0) == -1.0 and a.normalise(1023) == 1.0
    assert a.normalise(511.5) == 0.0
    assert a.normalise(511.5 + 0.09 * 511.5) == 0.0  # inside the deadzone
    assert a.normalise(5000) == 1.0  # out-of-range raw values saturate


@given(st.floats(-100, 1200), st.floats(0, 0.9))
def test_normalised_axis_is_bounded_and_monotone(raw: float, dz: float) -> None:
    a = AxisSpec(X, 0, 1023, deadzone=dz)
    v, v2 = a.normalise(raw), a.normalise(raw + 1)
    assert -1.0 <= v <= 1.0 and v <= v2


@given(st.floats(0, 0.5))
def test_deadzone_is_continuous_at_its_edge(dz: float) -> None:
    a = AxisSpec(X, -1000, 1000, deadzone=dz)
    edge = dz * 1000
    assert abs(a.normalise(edge + 1e-6)) < 1e-6


def test_extreme_3d_pro_defaults() -> None:
    m = JoystickMapping()
    full = {Y: 0, RZ: 127.5, THR: 0}  # stick forward, twist centred, slider at "+"
    c = command(m, full, {TRIG: 1})
    assert c.vx == pytest.approx(m.max_linear) and c.wz == 0.0 and c.deadman
    twist_right = command(m, {Y: 511.5, RZ: 255, THR: 0}, {TRIG: 1})
    assert twist_right.wz == pytest.approx(-m.max_angular) and twist_right.vx == 0.0
    half_speed = command(m, {Y: 0, THR: 127.5}, {TRIG: 1})
    assert half_speed.vx == pytest.approx(0.5 * m.max_linear)
    assert command(m, full, {TRIG: 0}).is_zero  # dead-man released
    assert command(m, full, {}).is_zero  # dead-man never seen


def test_axis_map_is_configurable() -> None:
    m = JoystickMapping(linear_y=AxisSpec.parse("-ABS_X"), deadman=None, speed_scale=None)
    c = command(m, {X: 1023}, {})
    assert c.vy == pytest.approx(-m.max_lateral)  # stick right → negative y (FLU)
    assert AxisSpec.parse("") is None
    assert AxisSpec.parse("ABS_THROTTLE").maximum == 255
    with pytest.raises(ValueError):
        AxisSpec.parse("ABS_NOPE")


def test_device_ranges_override_defaults() -> None:
    m = JoystickMapping().with_ranges({Y: (-32768, 32767)})
    assert (m.linear_x.minimum, m.linear_x.maximum) == (-32768, 32767)
    assert command(m, {Y: -32768, THR: 0}, {TRIG: 1}).vx == pytest.approx(0.5)


# -- gateway ----------------------------------------------------------------------------------


def gateway() -> JoystickGateway:
    g = JoystickGateway(JoystickMapping(), GatewayConfig(rate_hz=50))
    g.on_open(DeviceInfo("test", axes={Y: 511, RZ: 127, THR: 0}), 0.0)
    return g


def ev(*items: tuple[int, int, int]) -> list:
    from riskfield.edge.joystick.source import InputEvent

    return [InputEvent(0.0, *i) for i in items]


def test_changes_apply_on_syn_report_only() -> None:
    g = gateway()
    assert not g.on_events(ev((EV_KEY, TRIG, 1), (EV_ABS, Y, 0)))
    assert g.command.is_zero  # packet not complete yet
    assert g.on_events(ev((EV_SYN, SYN_REPORT, 0)))
    assert g.command.vx == pytest.approx(0.5)


def test_syn_dropped_releases_the_deadman_until_pressed_again() -> None:
    g = gateway()
    g.on_events(ev((EV_KEY, TRIG, 1), (EV_ABS, Y, 0), (EV_SYN, SYN_REPORT, 0)))
    assert not g.command.is_zero
    g.on_events(ev((EV_ABS, Y, 100), (EV_SYN, SYN_DROPPED, 0), (EV_ABS, Y, 200), (EV_SYN, SYN_REPORT, 0)))
    assert g.command.is_zero and g.syn_dropped == 1
    assert g.axes[Y] == 0  # the packet around the drop was discarded
    g.on_events(ev((EV_KEY, TRIG, 1), (EV_SYN, SYN_REPORT, 0)))
    assert g.command.vx == pytest.approx(0.5)


def test_publish_schedule() -> None:
    g = gateway()
    assert g.should_publish(0.0)
    g.published(0.0)
    assert not g.should_publish(0.01)
    assert g.should_publish(0.021)  # 50 Hz
    g.published(0.021)
    g.on_events(ev((EV_KEY, TRIG, 1), (EV_ABS, Y, 0), (EV_SYN, SYN_REPORT, 0)))
    assert g.should_publish(0.022)  # a change goes out at once


def test_device_loss_zeroes_and_reconnect_is_rate_limited() -> None:
    g = gateway()
    g.on_events(ev((EV_KEY, TRIG, 1), (EV_ABS, Y, 0), (EV_SYN, SYN_REPORT, 0)))
    g.on_lost(1.0)
    assert g.command.is_zero and not g.connected and g.losses == 1
    assert not g.open_due(1.5) and g.open_due(2.0)
    g.on_open_failed(2.0)
    assert not g.open_due(2.5)
    g.on_open(DeviceInfo("again", axes={Y: 0, THR: 0}, buttons={TRIG: 1}), 3.0)
    assert g.command.vx == pytest.approx(0.5)  # state read at open: held trigger, stick forward


def test_recorded_session_through_the_gateway() -> None:
    clock = Clock()
    src = RecordedSource([
        Session(packets((0.1, [(EV_KEY, TRIG, 1), (EV_ABS, Y, 0)]), (0.3, [(EV_KEY, TRIG, 0)])), lost_at=0.5),
        Session(packets((0.1, [(EV_KEY, TRIG, 1), (EV_ABS, RZ, 0)]))),
    ], clock=clock)
    g = JoystickGateway()
    seen = []
    for i in range(200):
        clock.t = i * 0.01
        if g.open_due(clock.t):
            try:
                g.on_open(src.open(), clock.t)
            except DeviceUnavailable:
                g.on_open_failed(clock.t)
        if g.connected:
            try:
                g.on_events(src.read())
            except DeviceLost:
                g.on_lost(clock.t)
        seen.append((round(clock.t, 2), g.command.vx, g.command.wz, g.connected))
    by_t = {t: (vx, wz, c) for t, vx, wz, c in seen}
    assert by_t[0.05] == (0.0, 0.0, True)
    assert by_t[0.2][0] > 0  # trigger + stick forward
    assert by_t[0.4] == (0.0, 0.0, True)  # trigger released
    assert by_t[0.55][2] is False  # lost
    assert src.opened == 2 and g.losses == 1
    reopened = next(t for t, *_, c in seen if t > 0.5 and c)
    assert reopened == pytest.approx(1.5, abs=0.011)  # reconnect_s = 1 s after the loss
    assert by_t[round(reopened + 0.15, 2)][1] > 0  # twist left after the second press


# -- raw event source -------------------------------------------------------------------------


def test_raw_source_reads_input_event_records_from_a_fifo(tmp_path: Path) -> None:
    fifo = tmp_path / "js"
    os.mkfifo(fifo)
    src = RawEventSource(str(fifo))
    src.open()
    try:
        assert src.read() == []  # no writer yet: nothing, no error
        w = os.open(fifo, os.O_WRONLY)
        data = pack_event(EV_KEY, TRIG, 1, 10.5) + pack_event(EV_ABS, Y, 7, 10.5) + pack_event(EV_SYN, 0, 0, 10.5)
        os.write(w, data[:30])  # records may arrive split
        first = src.read()
        os.write(w, data[30:])
        rest = src.read()
        os.close(w)
        events = first + rest
        assert [(e.type, e.code, e.value) for e in events] == [(EV_KEY, TRIG, 1), (EV_ABS, Y, 7), (EV_SYN, 0, 0)]
        assert events[0].t == pytest.approx(10.5)
        # The writer left: the hang-up is absorbed (no endless "readable"), a new writer is heard.
        assert src.read() == []
        assert select.select([src.fileno()], [], [], 0)[0] == []
        w = os.open(fifo, os.O_WRONLY)
        os.write(w, pack_event(EV_KEY, TRIG, 0))
        assert select.select([src.fileno()], [], [], 1.0)[0] == [src.fileno()]
        assert [(e.code, e.value) for e in src.read()] == [(TRIG, 0)]
        os.close(w)
    finally:
        src.close()


def test_raw_source_on_a_missing_path() -> None:
    with pytest.raises(DeviceUnavailable):
        RawEventSource("/nonexistent/event0").open()


def test_raw_source_replays_a_captured_file_without_a_wait_descriptor(tmp_path: Path) -> None:
    cap = tmp_path / "capture.bin"
    cap.write_bytes(pack_event(EV_KEY, TRIG, 1) + pack_event(EV_SYN, 0, 0))
    src = RawEventSource(str(cap))
    src.open()
    try:
        assert src.fileno() == -1  # a regular file is always readable: poll it instead
        assert len(src.read()) == 2 and src.read() == []
    finally:
        src.close()


def test_fd_waker_wakes_once_per_burst() -> None:
    from riskfield.edge.joystick.waker import FdWaker

    r, w = os.pipe()
    r2, w2 = os.pipe()
    woke: list[tuple[int, ...]] = []  # at each wake: which of r, r2 were readable
    # max_wait_s is long: within the test only drained() lets the waker wake again.
    waker = FdWaker(lambda: woke.append(tuple(select.select([r, r2], [], [], 0)[0])), max_wait_s=60)
    try:
        waker.watch(r)
        os.write(w, b"abc")
        assert wait_until(lambda: len(woke) == 1, 5)
        waker.drained()  # the loop did not read: still readable, so one more wake
        assert wait_until(lambda: len(woke) == 2, 5)
        os.read(r, 10)
        waker.drained()  # drained for real: nothing readable, no wake
        waker.watch(-1)
        os.write(w, b"x")  # readable again, but not watched: no wake
        waker.watch(r2)
        os.write(w2, b"y")
        # The third wake is r2's (both readable then): a wake on the empty or unwatched r would
        # have come first, seen r2 empty, and blocked the waker until drained().
        assert wait_until(lambda: len(woke) == 3, 5)
        assert woke == [(r,), (r,), (r, r2)]
    finally:
        waker.close()
        for fd in (r, w, r2, w2):
            os.close(fd)


def test_uinput_device_through_evdev(tmp_path: Path) -> None:
    """A virtual Extreme 3D Pro via uinput, read back by EvdevSource (skips without /dev/uinput)."""
    if not os.path.exists("/dev/uinput") or not os.access("/dev/uinput", os.W_OK):
        pytest.skip("/dev/uinput is not available here")
    import evdev
    from evdev import AbsInfo, UInput, ecodes

    from riskfield.edge.joystick.source import EvdevSource

    caps = {
        ecodes.EV_KEY: [ecodes.BTN_TRIGGER, ecodes.BTN_THUMB],
        ecodes.EV_ABS: [(ecodes.ABS_X, AbsInfo(512, 0, 1023, 0, 0, 0)), (ecodes.ABS_Y, AbsInfo(512, 0, 1023, 0, 0, 0)),
                        (ecodes.ABS_RZ, AbsInfo(128, 0, 255, 0, 0, 0)),
                        (ecodes.ABS_THROTTLE, AbsInfo(0, 0, 255, 0, 0, 0))],
    }
    with UInput(caps, name="Logitech Extreme 3D pro (test)", vendor=0x046D, product=0xC215) as ui:
        src = EvdevSource()
        infos = []

        def opened() -> bool:
            try:
                infos.append(src.open())
            except DeviceUnavailable:
                return False
            return True

        # The kernel creates the event node asynchronously: open as soon as it exists.
        assert wait_until(opened, 5.0)
        info = infos[-1]
        try:
            assert info.ranges[ecodes.ABS_Y] == (0, 1023)
            g = JoystickGateway()
            g.on_open(info, 0.0)
            ui.write(ecodes.EV_KEY, ecodes.BTN_TRIGGER, 1)
            ui.write(ecodes.EV_ABS, ecodes.ABS_Y, 0)
            ui.syn()
            assert wait_until(lambda: (g.on_events(src.read()), not g.command.is_zero)[1], 2.0, period_s=0.01)
            assert g.command.vx > 0
        finally:
            src.close()
    assert evdev is not None
