"""The link policy on the wire: every node publisher carries its key's QoS (protocol/keys.py ``QOS``)
through a real router, and the shipped router config downsamples what its consumers need less of."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
import zenoh

from riskfield.protocol import Image, NavGoal, SafetyStatus, VelocityCommand, encode
from riskfield.protocol.keys import QOS, STATUS_QOS, Qos, qos_of
from riskfield.services.runtime import Node, NodeSettings
from riskfield.services.runtime.session import endpoint_config
from riskfield.testing import client_session, free_port, query_barrier, wait_matched, wait_until

REPO = Path(__file__).resolve().parents[2]


class _Settings(NodeSettings):
    SERVICE: ClassVar[str] = "qos"


def test_qos_table_orders_control_above_maps_above_images() -> None:
    rank = {"real_time": 0, "interactive_high": 1, "interactive_low": 2, "data_high": 3, "data": 4,
            "data_low": 5, "background": 6}
    assert all(rank[QOS[k].priority] < rank[QOS["state"].priority] + 1 for k in ("cmd/safe", "cmd/ref"))
    assert rank[QOS["state"].priority] < rank[QOS["map/esdf"].priority] < rank[QOS["camera/image"].priority]
    assert QOS["cmd/safe"].express and QOS["cmd/ref"].express
    assert all(QOS[k].drop for k in ("camera/image", "perception/frame", "map/esdf", "sim/truth"))
    assert not QOS["nav/goal"].drop  # sent once: must arrive
    assert qos_of("status/mapping") == STATUS_QOS and qos_of(None) == Qos() and qos_of("no/such") == Qos()
    with pytest.raises(ValueError, match="priority"):
        Qos("urgent")


def test_node_publishers_carry_the_key_qos_through_the_router(router_endpoint: str) -> None:
    robot = "t_qos"
    got: dict[str, zenoh.Sample] = {}
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:
            got.setdefault(str(sample.key_expr).split(f"{robot}/", 1)[1], sample)

    node = Node("qos", _Settings(connect=[router_endpoint], robot=robot))
    try:
        with client_session(router_endpoint) as session:
            sub = session.declare_subscriber(f"rf/{robot}/**", on_sample)
            assert wait_matched(node.session, node.keys.cmd_safe)
            k = node.keys
            node.publish(k.cmd_safe, VelocityCommand(linear=(0.1, 0, 0), angular=(0, 0, 0), source="t"))
            node.publish(k.camera_image, Image(encoding="rgb8", width=2, height=2, data=np.zeros((2, 2, 3), np.uint8)))
            node.publish(k.nav_goal, NavGoal(waypoints=np.zeros((1, 3)), tolerance=0.1, loop=False))
            node.publish(k.status("qos"), node.status())
            node.publish_raw(k.state, b"raw")
            expected = {"cmd/safe": QOS["cmd/safe"], "camera/image": QOS["camera/image"],
                        "nav/goal": QOS["nav/goal"], "status/qos": STATUS_QOS, "state": QOS["state"]}
            assert wait_until(lambda: set(expected) <= set(got), 10.0), sorted(got)
            for rel, q in expected.items():
                s = got[rel]
                assert s.priority == getattr(zenoh.Priority, q.priority.upper()), rel
                cc = zenoh.CongestionControl.DROP if q.drop else zenoh.CongestionControl.BLOCK
                assert s.congestion_control == cc, rel
                assert s.express == q.express, rel
            sub.undeclare()
    finally:
        node.close()


@pytest.mark.parametrize("config", ["router.json5", "router-secure.json5"])
def test_shipped_router_configs_carry_the_link_policy(config: str) -> None:
    cfg = zenoh.Config.from_file(str(REPO / "deploy" / "zenoh" / config))
    (rule,) = json.loads(cfg.get_json("downsampling"))
    assert rule["flows"] == ["egress"] and rule["rules"] == [{"key_expr": "**/safety/status", "freq": 10.0}]
    assert json.loads(cfg.get_json("connect/retry"))["period_max_ms"] <= 1000  # back within 1 s of the link
    # The payloads cross the link, not a shared-memory segment beside it (two routers on one host).
    assert cfg.get_json("transport/shared_memory/enabled") == "false"
    # LZ4 between the sites' routers, as riskfield's router has it (RouterSettings.compression)
    assert cfg.get_json("transport/unicast/compression/enabled") == "true"


def test_router_downsamples_the_filter_status_to_10_hz() -> None:
    """A burst of statuses, faster than 10 Hz, through a router with the shipped config: one or two
    get through (the rule's 100 ms window), an ordinary key gets them all."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = endpoint_config("router", listen=[endpoint], base=REPO / "deploy" / "zenoh" / "router.json5",
                          extra={"plugins": {}})
    router = zenoh.open(cfg)
    try:
        with client_session(endpoint) as pub_s, client_session(endpoint) as sub_s:
            counts = {"safety/status": 0, "cmd/ref": 0}

            def on(sample: zenoh.Sample) -> None:
                counts[str(sample.key_expr).split("t_ds/", 1)[1]] += 1

            subs = [sub_s.declare_subscriber(f"rf/t_ds/{k}", on) for k in counts]
            assert wait_matched(pub_s, "rf/t_ds/safety/status") and wait_matched(pub_s, "rf/t_ds/cmd/ref")
            status = encode(SafetyStatus(h=1.0, risk_group=0, intervening=False, fallback=None, solve_us=1.0,
                                         esdf_age_ms=1.0))
            # BLOCK: a put's default congestion control (drop) gives up on a sample whose transmission
            # queue stays full (Zenoh's DEFAULT_CONFIG.json5, transport/link/tx/queue/congestion_control/
            # drop/wait_before_drop), which a loaded machine turns into lost puts; only the router drops here.
            block = zenoh.CongestionControl.BLOCK
            for _ in range(30):
                pub_s.put("rf/t_ds/safety/status", status, congestion_control=block)
                pub_s.put("rf/t_ds/cmd/ref", b"x", congestion_control=block)
            assert query_barrier(pub_s, sub_s)
            assert counts["cmd/ref"] == 30
            assert 1 <= counts["safety/status"] <= 5, counts
            for s in subs:
                s.undeclare()
    finally:
        router.close()
