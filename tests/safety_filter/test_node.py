"""The safety-filter node in its own process over a real Zenoh router on loopback."""

from __future__ import annotations

import math
import os
import signal
import threading
import time

import numpy as np
import pytest

from riskfield.protocol import (
    EsdfGrid,
    NodeStatus,
    RiskConfig,
    RiskGroup,
    RobotState,
    SafetyStatus,
    VelocityCommand,
)
from riskfield.services.fields import AnalyticField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Sphere
from riskfield.testing import (
    Collector,
    ServiceProcess,
    StatusWatch,
    client_session,
    hostile_payloads,
    put,
    wait_alive,
    wait_until,
)

GROUPS = ["high", "mid", "low"]


def grid(center=(1.0, 0.0), group=1) -> EsdfGrid:
    sphere = AnalyticField(Sphere([*center, 0.0], 0.3, planar=True, label=group), groups=GROUPS)
    return to_grid_message(to_esdf(sphere, [-1, -1, 0], [2, 1, 0], 0.05, planar=True))


def solid_grid() -> EsdfGrid:
    """Everything occupied (d = -1 everywhere): no input can satisfy the barrier."""
    return EsdfGrid(origin=(-1, -1, 0), voxel_size=0.1, distance=np.full((30, 20, 1), -1.0, np.float32),
                    risk_group=np.full((30, 20, 1), 3, np.uint8), groups=GROUPS, max_distance=2.0,
                    unknown_is_occupied=True)


def state(x=0.0, y=0.0, yaw=0.0) -> RobotState:
    return RobotState(position=(x, y, 0.0), orientation=(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
                      linear_velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0))


def ref(v=0.8) -> VelocityCommand:
    return VelocityCommand(linear=(v, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="test")


class Feeder:
    """Publishes map, state and reference periodically; each stream can be paused or changed."""

    def __init__(self, session, robot: str):
        self.session, self.root = session, f"rf/{robot}"
        self.msgs = {"map/esdf": grid(), "state": state(x=0.1), "cmd/ref": ref()}
        self.on = {"map/esdf": True, "state": True, "cmd/ref": True}
        self.rounds = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        k = 0
        while not self._stop.is_set():
            for key, msg in list(self.msgs.items()):
                if self.on[key] and (key != "map/esdf" or k % 2 == 0):
                    if key == "map/esdf":  # a live mapper: new content, so a new stamp
                        msg.header.stamp_ns = time.time_ns()
                    put(self.session, f"{self.root}/{key}", msg)
            k += 1
            self.rounds = k
            time.sleep(0.05)  # the sensors' 20 Hz (scenario), not a synchronisation

    def pause(self, key: str) -> None:
        """Stop streaming ``key``; returns once no put of it can still be under way."""
        self.on[key] = False
        r = self.rounds
        assert wait_until(lambda: self.rounds >= r + 2, 5.0)

    def __enter__(self) -> Feeder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2)


def latest(col: Collector):
    return col.items[-1] if col.items else None


def wait_fallback(col: Collector, reason: str | None, timeout: float = 8.0) -> SafetyStatus:
    ok = wait_until(lambda: latest(col) is not None and latest(col).fallback == reason, timeout)
    assert ok, f"wanted {reason!r}, last status {latest(col)}"
    return latest(col)


def test_every_fail_safe_path_in_its_own_process(router_endpoint):
    robot = "t_sf_paths"
    with ServiceProcess("safety-filter", router_endpoint, ["--robot", robot]) as proc, \
            client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/safety-filter"), proc.output
        status = Collector(session, f"rf/{robot}/safety/status", SafetyStatus)
        cmds = Collector(session, f"rf/{robot}/cmd/safe", VelocityCommand)
        # Nothing received yet: brake at the control rate, no map age.
        st = wait_fallback(status, "no_map")
        assert st.esdf_age_ms == -1.0 and st.h == 0.0
        n0 = len(status.items)
        assert wait_until(lambda: len(status.items) >= n0 + 5, 5.0)  # it keeps braking (its rate: a bench's business)
        assert all(s.fallback == "no_map" for s in status.items[n0:n0 + 5])
        put(session, f"rf/{robot}/map/esdf", grid())
        st = wait_fallback(status, "no_state")
        assert st.esdf_age_ms >= 0
        put(session, f"rf/{robot}/state", state(x=0.1))
        st = wait_fallback(status, "no_ref")
        assert st.h == pytest.approx(0.2, abs=0.01) and st.risk_group == 1  # clearance reported while braking
        with Feeder(session, robot) as feed:
            st = wait_fallback(status, None)
            assert st.intervening and 0 < st.h < 0.5 and st.risk_group == 1 and st.esdf_age_ms >= 0
            cmds.clear()
            assert wait_until(lambda: len(cmds.items) > 5)
            cmd = cmds.items[-1]
            assert 0 <= cmd.linear[0] < 0.8 and cmd.source == "safety-filter/test"
            for stream, reason in (("state", "stale_state"), ("map/esdf", "stale_map"), ("cmd/ref", "stale_ref")):
                feed.on[stream] = False
                wait_fallback(status, reason)
                cmds.clear()
                assert wait_until(lambda: len(cmds.items) > 2)
                assert all(c.linear == (0, 0, 0) and c.angular == (0, 0, 0) for c in cmds.items[1:])
                feed.on[stream] = True
                wait_fallback(status, None)
            # The look-ahead point leaves the map: a jump, announced (an unannounced one is refused).
            feed.msgs["state"] = state(x=1.9)
            put(session, f"rf/{robot}/state/relocalise", state(x=1.9))
            wait_fallback(status, "outside_map")
            feed.msgs["state"] = state(x=0.1)
            put(session, f"rf/{robot}/state/relocalise", state(x=0.1))
            wait_fallback(status, None)
            feed.msgs["map/esdf"] = solid_grid()
            st = wait_fallback(status, "infeasible")
            assert st.h < 0
            feed.msgs["map/esdf"] = grid()
            wait_fallback(status, None)
        status.close()
        cmds.close()
        assert proc.stop(signal.SIGTERM) == 0, proc.output
        assert "braking: stale_state" in proc.output


def test_hostile_payloads_on_every_key_brake_then_it_serves_again(router_endpoint):
    robot = "t_sf_fuzz"
    args = ["--robot", robot, "--set", "status_period_s=0.2"]
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/safety-filter"), proc.output
        status = Collector(session, f"rf/{robot}/safety/status", SafetyStatus)
        node_status = Collector(session, f"rf/{robot}/status/safety-filter", NodeStatus)
        with Feeder(session, robot) as feed:
            wait_fallback(status, None)
            samples = {"map/esdf": grid(), "state": state(x=0.1), "cmd/ref": ref(), "config/risk": RiskConfig()}
            for key, valid in samples.items():
                stream = key if key != "config/risk" else None
                if stream:
                    feed.pause(stream)
                payloads = hostile_payloads(valid, 150, seed=hash(key) % 1000)
                for payload in payloads:
                    put(session, f"rf/{robot}/{key}", payload)
                if stream:
                    reason = {"map/esdf": "invalid_map", "state": "invalid_state", "cmd/ref": "invalid_ref"}[stream]
                    wait_fallback(status, reason)
                    feed.on[stream] = True
                wait_fallback(status, None)
                assert proc.alive(), proc.output
            # Counters: every payload was received; those the latest-value queue did not skip were
            # rejected as invalid (counted by the node), none made a handler fail.
            def counted() -> bool:
                ns = latest(node_status)
                return ns is not None and all(
                    ns.received.get(k, 0) >= 150 and ns.extra.get(f"invalid_{w}", 0) >= 1
                    for k, w in (("map/esdf", "map"), ("state", "state"), ("cmd/ref", "ref"))
                ) and ns.received.get("config/risk", 0) >= 150 and ns.invalid.get("config/risk", 0) >= 1
            assert wait_until(counted, 10), latest(node_status)
            assert latest(node_status).errors == 0
        status.close()
        node_status.close()
        assert proc.stop() == 0
        assert proc.output.count("rejected a ref message") < 30  # rate-limited


def test_risk_configuration_hot_reloads_from_key_and_file(router_endpoint, tmp_path):
    robot = "t_sf_risk"
    risk_file = tmp_path / "risk.yaml"
    risk_file.write_text("groups: [{name: high, labels: [person], alpha: 0.6}, {name: low, alpha: 1.5}]\n"
                         "default_group: low\n")
    args = ["--robot", robot, "--set", f"risk_file={risk_file}", "--set", "risk_poll_s=0.2"]
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/safety-filter"), proc.output
        cmds = Collector(session, f"rf/{robot}/cmd/safe", VelocityCommand)
        status = Collector(session, f"rf/{robot}/safety/status", SafetyStatus)

        def speed() -> float:
            cmds.clear()
            assert wait_until(lambda: len(cmds.items) >= 3)
            return cmds.items[-1].linear[0]

        with Feeder(session, robot):
            wait_fallback(status, None)
            slow = speed()
            # A bolder high-risk gain over the config key: the same geometry allows more speed.
            put(session, f"rf/{robot}/config/risk",
                RiskConfig(groups=[RiskGroup(name="high", alpha=2.0), RiskGroup(name="low")], default_group="low"))
            assert wait_until(lambda: speed() > slow + 0.1), (slow, proc.output[-1500:])
            # ... and back through the watched file (a newer modification time).
            risk_file.write_text("groups: [{name: high, labels: [person, animal], alpha: 0.3}]\ndefault_group: high\n")
            os.utime(risk_file, ns=(time.time_ns(), time.time_ns() + 10**9))
            assert wait_until(lambda: speed() < slow - 0.02, 10), (slow, proc.output[-1500:])
            # A broken file is reported and the configuration in force stays.
            before = speed()
            risk_file.write_text("groups: [{name: high, alpha: -1}]\n")
            os.utime(risk_file, ns=(time.time_ns(), time.time_ns() + 2 * 10**9))
            assert wait_until(lambda: "not loaded" in proc.output, 10), proc.output[-1500:]
            assert speed() == pytest.approx(before, abs=0.02)
            assert wait_until(lambda: status.items and status.items[-1].risk_errors == 1, 5)  # counted once
        cmds.close()
        status.close()
        assert proc.stop() == 0
        assert wait_until(lambda: not wait_alive(session, f"rf/{robot}/alive/safety-filter", 0.5), 5)


def test_a_bad_risk_file_at_start_is_a_configuration_error(router_endpoint, tmp_path):
    bad = tmp_path / "risk.yaml"
    bad.write_text("groups: []\n")
    with ServiceProcess("safety-filter", router_endpoint, ["--robot", "t_sf_bad", "--set", f"risk_file={bad}"]) as p:
        assert wait_until(lambda: not p.alive(), 20)
        assert p.proc.returncode == 2, p.output
        assert "invalid configuration" in p.output


# -- the last word is a brake ------------------------------------------------------------------

#: The filter service with a fault injected from outside the shipped modules: once the trigger
#: file exists, either the supervisor's tick raises (a bug in the core, caught per step by the
#: runtime) or the node loop itself raises (the process ends with a traceback).
FAULTY_FILTER = """
import os, sys
mode, trigger = sys.argv[1], sys.argv[2]
from riskfield.services.runtime.node import Node
from riskfield.services.safety_filter.supervisor import FilterSupervisor
if mode == "handler":
    tick = FilterSupervisor.tick
    def faulty_tick(self, *a, **kw):
        if os.path.exists(trigger):
            raise RuntimeError("injected fault in the core")
        return tick(self, *a, **kw)
    FilterSupervisor.tick = faulty_tick
else:
    timers = Node._run_due_timers
    def faulty_timers(self):
        if os.path.exists(trigger):
            raise RuntimeError("injected fault in the loop")
        return timers(self)
    Node._run_due_timers = faulty_timers
from riskfield.cli import app
app(prog_name="riskfield", args=sys.argv[3:])
"""


def _moving(session, robot: str, proc) -> tuple[Collector, Collector]:
    """Collectors of cmd/safe and safety/status once the filter passes a moving command."""
    assert wait_alive(session, f"rf/{robot}/alive/safety-filter"), proc.output
    status = Collector(session, f"rf/{robot}/safety/status", SafetyStatus)
    cmds = Collector(session, f"rf/{robot}/cmd/safe", VelocityCommand)
    wait_fallback(status, None)
    assert wait_until(lambda: cmds.items and cmds.items[-1].linear[0] > 0.05), cmds.items[-3:]
    return status, cmds


def _last_word_is_a_brake(status: Collector, cmds: Collector, reason: str) -> None:
    # cmd/safe (real_time, express) and the status (interactive_low) travel in different priority
    # queues, so either may arrive first (CI: the status did, the brake came after): wait for both.
    assert wait_until(lambda: any(s.fallback == reason for s in status.items), 10.0), status.items[-3:]

    def braked() -> bool:
        last = cmds.items[-1]
        return last.linear == (0, 0, 0) and last.angular == (0, 0, 0) and last.source == "safety-filter"

    assert wait_until(braked, 10.0), cmds.items[-3:]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_the_last_cmd_safe_after_a_stop_signal_is_a_brake(router_endpoint, sig):
    robot = f"t_sf_last_{sig.name.lower()}"
    with ServiceProcess("safety-filter", router_endpoint, ["--robot", robot]) as proc, \
            client_session(router_endpoint) as session, Feeder(session, robot):
        status, cmds = _moving(session, robot, proc)
        assert proc.stop(sig) == 0, proc.output  # while the reference still asks to move
        _last_word_is_a_brake(status, cmds, "shutdown")
        assert "sent a brake" in proc.output


@pytest.mark.parametrize("mode", ["handler", "loop"])
def test_an_exception_in_a_step_brakes_and_one_that_ends_the_loop_brakes_last(router_endpoint, tmp_path, mode):
    from riskfield.testing import Child, service_argv

    robot, trigger = f"t_sf_fault_{mode}", tmp_path / f"fault-{mode}"
    argv = service_argv("safety-filter", ["--connect", router_endpoint, "--robot", robot])
    argv[1:3] = ["-c", FAULTY_FILTER, mode, str(trigger)]  # the same CLI, behind the injection
    proc = Child(mode, "safety-filter", argv).start()
    try:
        with client_session(router_endpoint) as session, Feeder(session, robot):
            status, cmds = _moving(session, robot, proc)
            trigger.touch()
            if mode == "handler":  # every step fails now, and every one of them brakes
                _last_word_is_a_brake(status, cmds, "internal_error")
                n = len(cmds.items)
                assert wait_until(lambda: len(cmds.items) >= n + 3), proc.output
                assert all(c.linear == (0, 0, 0) for c in cmds.items[n - 1:])
                assert proc.alive() and "injected fault in the core" in proc.output
                assert proc.stop(signal.SIGTERM)[0] == 0
                _last_word_is_a_brake(status, cmds, "shutdown")
            else:  # the loop dies: the close hook still sends the brake
                assert wait_until(lambda: not proc.alive(), 15.0), proc.output
                assert proc.returncode not in (0, None) and "injected fault in the loop" in proc.output
                _last_word_is_a_brake(status, cmds, "shutdown")
    finally:
        proc.stop(signal.SIGKILL, timeout_s=5.0)


def test_a_new_map_is_acted_on_at_once_not_at_the_next_tick(router_endpoint):
    # A control rate of one step per 30 s: the first tick comes long after the waits below, and no
    # reference is sent, so only the map's arrival can make the filter step and report it.
    # The state is in the inbox before the map is put (the node's status counts it), so the map's
    # step sees it; long state and map timeouts, so a loaded machine's delays between the two puts
    # and the step cannot turn the answer into stale_state or stale_map (their own tests are above).
    robot = "t_sf_step_on_map"
    args = ["--robot", robot, "--set", "rate_hz=0.0333", "--set", "status_period_s=0.1",
            "--set", "state_timeout_s=60", "--set", "map_timeout_s=30"]
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/safety-filter"), proc.output
        status = Collector(session, f"rf/{robot}/safety/status", SafetyStatus)
        node_status = StatusWatch(session, f"rf/{robot}/status/safety-filter")
        put(session, f"rf/{robot}/state", state(x=0.1))
        node_status.wait(lambda st: st.received.get("state", 0) >= 1)
        m = grid()
        m.header.stamp_ns = time.time_ns()
        put(session, f"rf/{robot}/map/esdf", m)
        assert wait_until(lambda: any(s.esdf_age_ms >= 0 for s in status.items), 10.0), proc.output
        st = next(s for s in status.items if s.esdf_age_ms >= 0)
        assert st.fallback == "no_ref" and st.h == pytest.approx(0.2, abs=0.01)  # the map is in force
        status.close()
        node_status.close()
