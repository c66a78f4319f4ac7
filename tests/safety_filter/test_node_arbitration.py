"""The safety-filter node's cmd/ref arbitration and its versioned risk configuration, in its own
process over a real Zenoh router on loopback."""

from __future__ import annotations

import threading
import time

import msgpack
from safety_filter.test_node import grid, latest, state, wait_fallback

from riskfield.protocol import CommandLock, RiskConfig, RiskGroup, SafetyStatus, VelocityCommand, to_map
from riskfield.testing import (
    Collector,
    ServiceProcess,
    StatusWatch,
    client_session,
    put,
    wait_alive,
    wait_matched,
    wait_until,
)


class Sources:
    """Map and state at the sensors' 20 Hz, and a navigator and (when on) a joystick on cmd/ref,
    interleaved in one thread, as two publishers reach the filter."""

    def __init__(self, session, robot: str, keyed: bool = False):
        self.session, self.root = session, f"rf/{robot}"
        # keyed: each source on its own cmd/ref/<source> (protocol.keys.REF_SOURCES), else the plain key
        self.keys = {n: f"{self.root}/cmd/ref/{n}" if keyed else f"{self.root}/cmd/ref"
                     for n in ("navigator", "joystick")}
        self.forged: list[tuple[str, VelocityCommand]] = []  # (key, message) put each cycle too
        self.joystick: VelocityCommand | None = None
        self.navigator = VelocityCommand(linear=(0.3, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="navigator")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        esdf, st = grid(center=(1.5, 0.0)), state(x=0.0)
        while not self._stop.is_set():
            esdf.header.stamp_ns = time.time_ns()
            put(self.session, f"{self.root}/map/esdf", esdf)
            put(self.session, f"{self.root}/state", st)
            put(self.session, self.keys["navigator"], self.navigator)
            for key, msg in list(self.forged):
                put(self.session, key, msg)
            joystick = self.joystick
            if joystick is not None:
                put(self.session, self.keys["joystick"], joystick)
            time.sleep(0.05)  # the sources' 20 Hz (not a synchronisation)

    def __enter__(self) -> Sources:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2)


def stick(v: float, engaged: bool) -> VelocityCommand:
    return VelocityCommand(linear=(v, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="joystick", engaged=engaged)


def test_the_joystick_outranks_the_navigator_which_takes_over_after_its_timeout_and_a_lock_brakes(
        router_endpoint):
    robot = "t_sf_mux"
    args = ["--robot", robot, "--set", "status_period_s=0.2"]
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/safety-filter"), proc.output
        status = Collector(session, f"rf/{robot}/safety/status", SafetyStatus)
        cmds = Collector(session, f"rf/{robot}/cmd/safe", VelocityCommand)
        counters = StatusWatch(session, f"rf/{robot}/status/safety-filter")
        with Sources(session, robot) as src:
            st = wait_fallback(status, None)
            assert wait_until(lambda: latest(status).ref_source == "navigator", 5), latest(status)
            # The joystick joins, interleaved with the navigator: it wins, and only its commands pass.
            src.joystick = stick(0.1, engaged=True)
            assert wait_until(lambda: latest(status).ref_source == "joystick", 5), latest(status)
            cmds.clear()
            assert wait_until(lambda: len(cmds.items) >= 10, 5)
            assert {c.source for c in cmds.items[1:]} == {"safety-filter/joystick"}
            assert all(c.linear[0] <= 0.1 + 1e-9 for c in cmds.items[1:])
            counters.wait(lambda ns: ns.extra.get("ref_refused_preempted", 0) >= 5)
            # The dead-man released: zeros that claim nothing; the navigator drives once the
            # joystick's claim has timed out (0.5 s, ref_sources).
            src.joystick = stick(0.0, engaged=False)
            assert wait_until(lambda: latest(status).ref_source == "navigator", 5), latest(status)
            cmds.clear()
            assert wait_until(lambda: len(cmds.items) >= 5 and cmds.items[-1].source == "safety-filter/navigator", 5)
            assert cmds.items[-1].linear[0] > 0.05
            counters.wait(lambda ns: ns.extra.get("ref_refused_idle", 0) >= 1)
            # A lock brakes whoever drives, and says so; its release lets the navigator drive again.
            put(session, f"rf/{robot}/cmd/lock", CommandLock(locked=True, source="estop"))
            st = wait_fallback(status, "locked")
            assert st.ref_source is None
            cmds.clear()
            assert wait_until(lambda: len(cmds.items) >= 5, 5)
            assert all(c.linear == (0, 0, 0) and c.angular == (0, 0, 0) for c in cmds.items[1:])
            src.joystick = stick(0.1, engaged=True)  # a lock at the default priority (255) holds the joystick too
            assert wait_until(lambda: len(cmds.items) >= 15, 5)
            assert all(c.linear == (0, 0, 0) for c in cmds.items[1:]) and latest(status).fallback == "locked"
            src.joystick = None
            put(session, f"rf/{robot}/cmd/lock", CommandLock(locked=False, source="estop"))
            wait_fallback(status, None)
            assert wait_until(lambda: latest(status).ref_source == "navigator", 5), latest(status)
        status.close()
        cmds.close()
        counters.close()
        assert proc.stop() == 0, proc.output


def test_a_source_is_the_key_it_puts_on_so_no_one_takes_the_joysticks_priority_or_lock(router_endpoint):
    """With ref_plain_key=false (a secure site, whose routers let only a source's identity
    put cmd/ref/<source>), a command that declares the joystick on the operator's key, or on the
    plain key, is refused and counted, and so is a lock put under another source's name; the
    joystick on its own key still wins, and a lock on the operator's own key still brakes."""
    robot = "t_sf_keyed"
    args = ["--robot", robot, "--set", "status_period_s=0.2", "--set", "ref_plain_key=false"]
    root = f"rf/{robot}"
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as session:
        assert wait_alive(session, f"{root}/alive/safety-filter"), proc.output
        status = Collector(session, f"{root}/safety/status", SafetyStatus)
        cmds = Collector(session, f"{root}/cmd/safe", VelocityCommand)
        counters = StatusWatch(session, f"{root}/status/safety-filter")
        with Sources(session, robot, keyed=True) as src:
            wait_fallback(status, None)
            assert wait_until(lambda: latest(status).ref_source == "navigator", 5), latest(status)
            fast = stick(0.6, engaged=True)
            # The operator's identity claims the joystick on its own key; anyone on the plain key.
            src.forged = [(f"{root}/cmd/ref/operator", fast), (f"{root}/cmd/ref", fast)]
            counters.wait(lambda ns: ns.extra.get("ref_refused_source_mismatch", 0) >= 10
                          and ns.extra.get("ref_refused_plain_key", 0) >= 10)
            cmds.clear()
            assert wait_until(lambda: len(cmds.items) >= 10, 5)
            assert {c.source for c in cmds.items} == {"safety-filter/navigator"}, latest(status).fallback
            assert latest(status).ref_source == "navigator"
            # Locks: under another's name, or on the plain key, nothing; on the operator's own key, a brake.
            put(session, f"{root}/cmd/lock/navigator", CommandLock(locked=True, source="operator"))
            put(session, f"{root}/cmd/lock", CommandLock(locked=True, source="operator"))
            counters.wait(lambda ns: ns.extra.get("lock_refused_source_mismatch", 0) >= 1
                          and ns.extra.get("lock_refused_plain_key", 0) >= 1)
            assert latest(status).fallback is None and latest(status).ref_source == "navigator"
            put(session, f"{root}/cmd/lock/operator", CommandLock(locked=True, source="operator"))
            wait_fallback(status, "locked")
            put(session, f"{root}/cmd/lock/navigator", CommandLock(locked=False, source="operator"))  # refused
            counters.wait(lambda ns: ns.extra.get("lock_refused_source_mismatch", 0) >= 2)
            assert latest(status).fallback == "locked"
            put(session, f"{root}/cmd/lock/operator", CommandLock(locked=False, source="operator"))
            wait_fallback(status, None)
            # The joystick on its own key takes over.
            src.joystick = stick(0.1, engaged=True)
            assert wait_until(lambda: latest(status).ref_source == "joystick", 5), latest(status)
        for c in (status, cmds, counters):
            c.close()
        assert proc.stop() == 0, proc.output


def test_a_wire_risk_config_is_versioned_kept_across_a_restart_and_one_naming_no_obstacle_is_refused(
        router_endpoint, tmp_path):
    robot = "t_sf_riskver"
    args = ["--robot", robot, "--set", "status_period_s=0.2", "--set", f"state_dir={tmp_path}"]
    bolder = RiskConfig(groups=[RiskGroup(name="high", alpha=2.0), RiskGroup(name="low")], default_group="low")
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/safety-filter"), proc.output
        status = Collector(session, f"rf/{robot}/safety/status", SafetyStatus)
        counters = StatusWatch(session, f"rf/{robot}/status/safety-filter")
        assert wait_until(lambda: latest(status) is not None, 5)
        assert (latest(status).risk_version, latest(status).risk_hash) == (0, RiskConfig().digest())
        put(session, f"rf/{robot}/config/risk", bolder)
        assert wait_until(lambda: latest(status).risk_version == 1, 5), latest(status)
        assert latest(status).risk_hash == bolder.digest()
        ns = counters.wait(lambda ns: ns.risk_version == 1)
        assert ns.risk_hash == bolder.digest()
        # default_group null and no labels: every obstacle free. Refused, counted, said; v1 stays.
        hostile = dict(to_map(bolder), groups=[{"name": "low", "labels": []}], default_group=None, free_labels=[])
        put(session, f"rf/{robot}/config/risk", msgpack.packb(hostile))
        ns = counters.wait(lambda ns: ns.invalid.get("config/risk", 0) >= 1)
        assert ns.risk_version == 1 and latest(status).risk_hash == bolder.digest()
        assert wait_until(lambda: "no obstacle labels" in proc.output, 5), proc.output[-2000:]
        status.close()
        counters.close()
        assert proc.stop() == 0, proc.output
    assert (tmp_path / "risk-safety-filter.json").is_file()
    # The next start reloads the configuration in force, with its version.
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/safety-filter"), proc.output
        status = Collector(session, f"rf/{robot}/safety/status", SafetyStatus)
        assert wait_until(lambda: latest(status) is not None, 5)
        assert (latest(status).risk_version, latest(status).risk_hash) == (1, bolder.digest())
        status.close()
        assert proc.stop() == 0, proc.output


def test_on_the_plain_key_no_sources_reference_displaces_anothers_before_the_arbitration_sees_it(router_endpoint):
    """Two sources on the plain cmd/ref, faster than the node's loop takes them (here: not at all until
    the burst is in): every reference waits its turn. With one newest-value slot the joystick's
    would displace the navigator's claims, and its input would time out on a busy machine."""
    from riskfield.services.runtime import Node
    from riskfield.services.safety_filter.node import PLAIN_REF_BACKLOG, SERVICE

    robot = "t_sf_plain"
    settings = SERVICE.settings(connect=[router_endpoint], robot=robot)
    node = Node(SERVICE.name, settings)
    try:
        SERVICE.setup(node, settings)  # subscribed; the loop (node.run) is not running
        (sub,) = [s for s in node._subs if s.key == node.keys.cmd_ref]
        with client_session(router_endpoint) as session:
            assert wait_matched(session, node.keys.cmd_ref)
            burst = [VelocityCommand(linear=(0.3, 0, 0), angular=(0, 0, 0), source="navigator"),
                     stick(0.1, engaged=True)] * (PLAIN_REF_BACKLOG // 2)
            for m in burst:
                put(session, node.keys.cmd_ref, m)
            assert wait_until(lambda: sub.slot.received == len(burst), 5), sub.slot.received
        sources = [msgpack.unpackb(item[2])["source"] for item, _ in sub.slot.items]
        assert sources == [m.source for m in burst] and sub.slot.dropped == 0
    finally:
        node.close()
