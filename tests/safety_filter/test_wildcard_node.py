"""Defence in depth over a plain router (no access control): the safety filter, in its own
process, never takes a reference, map or state put on a wildcard key expression."""

from __future__ import annotations

from riskfield.protocol import Keys, NodeStatus, SafetyStatus, VelocityCommand
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_until

from .test_map_freshness_node import robot_state, sphere


def test_forged_wildcard_references_never_drive_the_filter(router_endpoint: str) -> None:
    keys = Keys("t_sf_wild")
    forged = VelocityCommand(linear=(0.5, 0, 0), angular=(0, 0, 0), source="forged")
    wild = [f"rf/{keys.robot}/cmd/*", f"rf/{keys.robot}/**", "rf/*/cmd/ref", f"rf/{keys.robot}/*/ref"]
    args = ["--robot", keys.robot, "--set", "status_period_s=0.2"]
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("safety-filter")), proc.output
        status = Collector(s, keys.safety_status, SafetyStatus)
        node_status = Collector(s, keys.status("safety-filter"), NodeStatus)

        def attack() -> bool:
            put(s, keys.esdf, sphere(1.0))  # fresh map and state: only the reference is missing
            put(s, keys.state, robot_state())
            for key in wild:
                put(s, key, forged)
            st = node_status.items[-1] if node_status.items else None
            return st is not None and st.extra.get("wildcard_dropped", 0) >= 40

        assert wait_until(attack, timeout_s=30, period_s=0.05), proc.output
        assert status.items and all(st.fallback in ("no_map", "no_state", "no_ref") for st in status.items)
        assert status.items[-1].fallback == "no_ref"
        assert "dropped a sample on" in proc.output
        # the exact key still works
        def legit() -> bool:
            put(s, keys.esdf, sphere(1.0))
            put(s, keys.state, robot_state())
            put(s, keys.cmd_ref, VelocityCommand(linear=(0.2, 0, 0), angular=(0, 0, 0), source="legit"))
            return status.items[-1].fallback is None

        assert wait_until(legit, 10, period_s=0.05), status.items[-1]
        status.close()
        node_status.close()
        assert proc.stop() == 0, proc.output
