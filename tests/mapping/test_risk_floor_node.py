"""The mapping node under a hostile risk configuration, in its own process over a real router: the
floor keeps what the map holds an obstacle, a configuration naming no obstacle is refused, and the
configuration in force is echoed in ``status/mapping`` with its version and hash."""

from __future__ import annotations

import msgpack
import numpy as np
from mapping.test_node import ask, feed, frames, ready

from riskfield.protocol import EsdfGrid, Keys, RiskConfig, RiskGroup, ade20k, to_map
from riskfield.testing import Collector, ServiceProcess, StatusWatch, client_session, put, wait_until

BY_THE_WALL = np.array([[1.3, 0.0, 0.3], [1.35, 0.1, 0.3]])  # the room's wall is the plane x = 1.5


def test_default_group_null_leaves_the_wall_an_obstacle_and_the_version_is_reported(router_endpoint, tmp_path):
    keys = Keys("t_map_floor")
    args = ["--robot", keys.robot, "--set", "esdf_rate_hz=20", "--set", "status_period_s=0.1",
            "--set", f"state_dir={tmp_path}"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert ready(s, keys), proc.output
        grids = Collector(s, keys.esdf, EsdfGrid)
        status = StatusWatch(s, keys.status("mapping"))
        assert status.wait(lambda ns: ns.risk_version == 0).risk_hash == RiskConfig().digest()
        feed(s, keys, frames(3), grids)
        grids.wait(1)
        before = ask(s, keys, BY_THE_WALL)
        assert np.all(before.distance < 0.3) and np.all(before.risk_group == 3), before
        # Only people listed, everything else left to default_group null: on today's wire that
        # made the wall free space. The floor keeps it in the last group.
        people_only = RiskConfig(groups=[RiskGroup(name="high", labels=[ade20k.index("person")], margin=0.15),
                                         RiskGroup(name="low")], default_group=None)
        n = len(grids.items)
        put(s, keys.risk_config, people_only)
        grids.wait(n + 1)
        after = ask(s, keys, BY_THE_WALL)
        assert np.allclose(after.distance, before.distance, atol=1e-5) and np.all(after.risk_group == 2), after
        ns = status.wait(lambda ns: ns.risk_version == 1)
        assert ns.risk_hash == people_only.digest()
        assert "stay obstacles of 'low' (the floor)" in proc.output
        # No obstacle named at all: refused at the door, counted, logged; version 1 stays.
        hostile = dict(to_map(people_only), groups=[{"name": "low", "labels": []}], default_group=None)
        put(s, keys.risk_config, msgpack.packb(hostile))
        ns = status.wait(lambda ns: ns.invalid.get("config/risk", 0) >= 1)
        assert (ns.risk_version, ns.risk_hash) == (1, people_only.digest())
        assert wait_until(lambda: "no obstacle labels" in proc.output, 5)
        assert np.allclose(ask(s, keys, BY_THE_WALL).distance, before.distance, atol=1e-5)
        status.close()
        grids.close()
        assert proc.stop() == 0
    assert (tmp_path / "risk-mapping.json").is_file()
