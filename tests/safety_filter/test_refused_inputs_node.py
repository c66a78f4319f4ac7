"""Refused inputs move nothing, over a real Zenoh router with the filter in its own process: a
state that jumps farther than the robot can move is refused unless announced on
``state/relocalise``, a future-stamped state is refused, and a forged map that copies the live
mapper's source id with seq 2^64 - 1 is refused without locking that mapper out."""

from __future__ import annotations

import threading
import time

import zenoh

from riskfield.protocol import (
    ENCODING,
    EsdfGrid,
    Header,
    Keys,
    RobotState,
    SafetyStatus,
    VelocityCommand,
    encode,
)
from riskfield.services.fields import AnalyticField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Sphere
from riskfield.testing import Collector, ServiceProcess, StatusWatch, client_session, put, wait_alive, wait_until

GROUPS = ["high", "mid", "low"]


def sphere(x: float) -> EsdfGrid:
    ball = AnalyticField(Sphere([x, 0.0, 0.0], 0.3, planar=True, label=1), groups=GROUPS)
    return to_grid_message(to_esdf(ball, [-1, -1, 0], [2, 1, 0], 0.05, planar=True))


def robot_state(x: float = 0.0, stamp_ns: int | None = None) -> RobotState:
    header = Header() if stamp_ns is None else Header(stamp_ns=stamp_ns)
    return RobotState(header=header, position=(x, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0),
                      linear_velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0))


class Live:
    """A live robot at 20 Hz: state at ``x``, a reference, and a mapper's fresh maps with the
    runtime's header seq and Zenoh source info (its own session: its own publisher id)."""

    def __init__(self, endpoint: str, keys: Keys, grid: EsdfGrid):
        self.keys, self.grid, self.x = keys, grid, 0.0
        self._cm = client_session(endpoint)
        self.session = self._cm.__enter__()
        self.map_pub = self.session.declare_publisher(keys.esdf, encoding=zenoh.Encoding(ENCODING))
        self.seq = 0
        # Cleared (hold): the mapper holds its maps, the robot its states (the reference goes on).
        self.maps, self.states = threading.Event(), threading.Event()
        self.maps.set()
        self.states.set()
        self._lock = threading.Lock()  # one iteration's puts
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                if self.maps.is_set():
                    self.seq += 1
                    g = self.grid.model_copy(deep=False)
                    g.header = Header(stamp_ns=time.time_ns(), seq=self.seq)
                    self.map_pub.put(encode(g), source_info=zenoh.SourceInfo(self.map_pub.id, self.seq))
                if self.states.is_set():
                    put(self.session, self.keys.state, robot_state(self.x))
                put(self.session, self.keys.cmd_ref, VelocityCommand(linear=(0.3, 0, 0), angular=(0, 0, 0),
                                                                     source="t"))
            time.sleep(0.05)  # the sensors' 20 Hz (scenario), not a synchronisation

    def hold(self, maps: bool = False, states: bool = False) -> None:
        """Stop putting maps and/or states: once this returns, none is put until ``resume``."""
        with self._lock:
            if maps:
                self.maps.clear()
            if states:
                self.states.clear()

    def hold_and_put(self, key: str, payload: bytes, source_info: zenoh.SourceInfo | None = None) -> None:
        """Hold the live maps (``key`` is the map key) or states (any other) and put the test's own
        sample from this session. Held alone, a live sample put just before the hold may still reach
        the filter after a sample from another session (the router keeps order per link, not across
        links), and the latest-value inbox drops the test's unjudged (CI: a future-stamped state never
        judged). From the live session's own link, the test's sample follows every live one."""
        self.hold(maps=key == self.keys.esdf, states=key != self.keys.esdf)
        with self._lock:
            self.session.put(key, payload, encoding=zenoh.Encoding(ENCODING), source_info=source_info)

    def resume(self) -> None:
        with self._lock:
            self.maps.set()
            self.states.set()

    def __enter__(self) -> Live:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2)
        self.map_pub.undeclare()
        self._cm.__exit__(None, None, None)


def filter_process(endpoint: str, keys: Keys) -> ServiceProcess:
    return ServiceProcess("safety-filter", endpoint, ["--robot", keys.robot, "--set", "status_period_s=0.1"])


def extra(st, name: str) -> float:
    return st.extra.get(name, 0.0)


def test_a_state_jump_is_refused_unless_announced_and_a_future_state_is_refused(router_endpoint: str) -> None:
    keys = Keys("t_sf_jump")
    with filter_process(router_endpoint, keys) as proc, client_session(router_endpoint) as s, \
            Live(router_endpoint, keys, sphere(1.2)) as live:
        assert wait_alive(s, keys.alive("safety-filter")), proc.output
        status = Collector(s, keys.safety_status, SafetyStatus)
        node = StatusWatch(s, keys.status("safety-filter"))
        assert wait_until(lambda: status.items and status.items[-1].fallback is None, 20), proc.output
        # One sample 1.9 m away, 50 ms after the last: the look-ahead point would leave the map.
        # (While the robot's states hold, the filter may brake for a stale state, never otherwise.)
        n = len(status.items)
        live.hold_and_put(keys.state, encode(robot_state(1.9)))
        node.wait(lambda st: extra(st, "state_refused_state_jump") >= 1)
        live.resume()
        later = len(status.items)
        assert wait_until(lambda: len(status.items) > later + 3 and status.items[-1].fallback is None, 5)
        taken = [st.fallback for st in status.items[n:] if st.fallback not in (None, "stale_state")]
        assert not taken, taken
        # Stamped 10 s ahead of this clock: refused too.
        live.hold_and_put(keys.state, encode(robot_state(0.0, stamp_ns=time.time_ns() + 10_000_000_000)))
        node.wait(lambda st: extra(st, "state_refused_future_state") >= 1)
        live.resume()
        # Announced, the same jump is taken: the robot is where the map ends.
        live.x = 1.9
        put(s, keys.key("state/relocalise"), robot_state(1.9))
        assert wait_until(lambda: status.items[-1].fallback == "outside_map", 10), proc.output
        assert "refused a state" in proc.output
        status.close()
        node.close()
        assert proc.stop() == 0, proc.output


def test_a_forged_map_with_the_live_mappers_id_and_a_huge_seq_does_not_lock_it_out(router_endpoint: str) -> None:
    keys = Keys("t_sf_forge")
    with filter_process(router_endpoint, keys) as proc, client_session(router_endpoint) as s, \
            Live(router_endpoint, keys, sphere(0.6)) as live:
        assert wait_alive(s, keys.alive("safety-filter")), proc.output
        status = Collector(s, keys.safety_status, SafetyStatus)
        node = StatusWatch(s, keys.status("safety-filter"))
        assert wait_until(lambda: status.items and status.items[-1].fallback is None, 20), proc.output
        h_near = status.items[-1].h
        # The live mapper's source id, the largest seq, a stamp 1 h ahead (the filter tells a
        # publisher by its source id alone, so the forger's link is immaterial).
        forged = sphere(1.6)
        forged.header = Header(stamp_ns=time.time_ns() + 3600 * 1_000_000_000, seq=2**64 - 1)
        live.hold_and_put(keys.esdf, encode(forged), zenoh.SourceInfo(live.map_pub.id, 0))
        node.wait(lambda st: extra(st, "map_refused_future_map") >= 1)
        # The live mapper goes on (its seq grows from where it was) with a new map: it is taken.
        live.grid = sphere(1.6)
        live.resume()
        assert wait_until(lambda: status.items[-1].fallback is None and status.items[-1].h > h_near + 0.5, 10), (
            status.items[-1], proc.output)
        assert extra(node.latest, "map_refused_seq_backwards") == 0
        status.close()
        node.close()
        assert proc.stop() == 0, proc.output
