"""Nodes over a real Zenoh router on an ephemeral loopback port."""

from __future__ import annotations

import signal
import threading
from typing import ClassVar

import numpy as np
import pytest

from riskfield.protocol import (
    DecodeError,
    DistanceQuery,
    DistanceReply,
    EsdfGrid,
    NodeStatus,
    VelocityCommand,
    decode,
)
from riskfield.services.runtime import Node, NodeSettings
from riskfield.testing import Collector, ServiceProcess, client_session, hostile_payloads, put, wait_alive, wait_until


def _grid() -> EsdfGrid:
    return EsdfGrid(origin=(0, 0, 0), voxel_size=0.05, distance=np.linspace(-1, 1, 60).reshape(3, 4, 5),
                    risk_group=np.ones((3, 4, 5), np.uint8), groups=["high"], max_distance=2.0,
                    unknown_is_occupied=False)


def test_relay_process_survives_1000_hostile_payloads_then_serves(router_endpoint):
    robot = "t_relay"
    args = ["--robot", robot, "--set", "schema_name=EsdfGrid/1", "--set", "in_key=map/in",
            "--set", "out_key=map/out", "--set", "status_period_s=0.2"]
    with ServiceProcess("relay", router_endpoint, args) as relay, client_session(router_endpoint) as session:
        assert wait_alive(session, f"rf/{robot}/alive/relay"), relay.output
        out = Collector(session, f"rf/{robot}/map/out", EsdfGrid)
        status = Collector(session, f"rf/{robot}/status/relay", NodeStatus)
        valid = _grid()
        for payload in hostile_payloads(valid, 1000, seed=1):
            put(session, f"rf/{robot}/map/in", payload)
        put(session, f"rf/{robot}/map/in", valid)
        got = out.wait(1, timeout_s=20)
        assert len(got) == 1  # nothing hostile came through
        np.testing.assert_array_equal(got[0].distance, valid.distance)
        # A status from after the valid grid went out: the inbox is fifo, so every hostile payload put
        # before it has been judged by then (one from before it counted arrivals, not yet the refusals:
        # CI saw 244 refused of 1001 received).
        assert wait_until(lambda: status.items and status.items[-1].received.get("map/in", 0) == 1001
                          and status.items[-1].published.get("map/out", 0) == 1, 20), (
            status.items[-1:], relay.output[-2000:])
        last = status.items[-1]
        # Each hostile payload is decoded and refused, or, when a loaded machine lets the 1001 puts
        # outrun the loop, dropped unread by the inbox's bound (fifo, 1000: oldest first, counted).
        refused, dropped = last.invalid.get("map/in", 0), last.dropped.get("map/in", 0)
        assert refused + dropped == 1000 and refused > 0, (refused, dropped)
        assert last.published["map/out"] == 1 and last.errors == 0
        assert relay.alive()
        assert relay.stop(signal.SIGTERM) == 0
        log = relay.output
        assert "rejected a message on rf/t_relay/map/in" in log
        assert log.count("rejected a message") < 50  # rate-limited, not one line per payload
        out.close()
        status.close()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_router_process_stops_cleanly(sig, router_endpoint):
    from riskfield.testing import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with ServiceProcess("router", endpoint) as router, client_session(endpoint) as session:
        assert wait_alive(session, "rf/limo1/alive/router"), router.output
        assert router.stop(sig) == 0, router.output


class EchoSettings(NodeSettings):
    SERVICE: ClassVar[str] = "echo"


def test_in_process_node_queries_errors_and_liveliness(router_endpoint):
    settings = EchoSettings(connect=[router_endpoint], robot="t_echo", status_period_s=0.2)
    node = Node("echo", settings)
    seen: list[VelocityCommand] = []

    def on_cmd(msg: VelocityCommand) -> None:
        if msg.source == "boom":
            raise RuntimeError("handler bug")
        seen.append(msg)

    def on_query(q: DistanceQuery) -> DistanceReply:
        n = q.points.shape[0]
        return DistanceReply(distance=np.linalg.norm(q.points, axis=1), gradient=np.zeros((n, 3)),
                             risk_group=np.zeros(n, np.uint8))

    node.subscribe(node.keys.cmd_ref, VelocityCommand, on_cmd, queue="fifo")
    node.queryable(node.keys.esdf_query, DistanceQuery, on_query)
    thread = threading.Thread(target=node.run, daemon=True)
    thread.start()
    try:
        with client_session(router_endpoint) as session:
            assert wait_alive(session, "rf/t_echo/alive/echo")
            put(session, "rf/t_echo/cmd/ref", VelocityCommand.zero("boom"))
            put(session, "rf/t_echo/cmd/ref", VelocityCommand.zero("ok"))
            assert wait_until(lambda: len(seen) == 1, 10)  # a failing handler did not stop the node
            client = Node("client", EchoSettings(connect=[router_endpoint], robot="t_echo"), session=session)
            replies = client.query("rf/t_echo/map/esdf/query", DistanceQuery(points=[[3, 4, 0], [0, 0, 1]]),
                                   DistanceReply, timeout_s=5)
            assert len(replies) == 1
            np.testing.assert_allclose(replies[0].distance, [5, 1])
            bad = list(session.get("rf/t_echo/map/esdf/query", payload=b"junk", timeout=5))
            assert len(bad) == 1 and bad[0].err is not None
            assert "not msgpack" in bad[0].err.payload.to_string()
            client.close()
            assert wait_until(lambda: node.status().errors == 1, 5)
            st = node.status()
            assert st.received["cmd/ref"] == 2 and st.invalid["map/esdf/query"] == 1
    finally:
        node.stop()
        thread.join(10)
    assert not thread.is_alive()
    with client_session(router_endpoint) as session:
        assert wait_until(lambda: not list(session.liveliness().get("rf/t_echo/alive/echo", timeout=0.3)), 5)


def test_collector_decodes(router_endpoint):
    with client_session(router_endpoint) as session:
        c = Collector(session, "rf/t_col/x", None)
        put(session, "rf/t_col/x", b"raw")
        assert c.wait(1) == [b"raw"]
        c.close()
    with pytest.raises(DecodeError):
        decode(b"raw")


def test_post_runs_on_the_loop_thread_and_close_hooks_publish(router_endpoint):
    settings = EchoSettings(connect=[router_endpoint], robot="t_post")
    node = Node("echo", settings)
    ran_on: list[str] = []
    node.on_close(lambda: node.publish(node.keys.cmd_safe, VelocityCommand.zero("last words")))
    thread = threading.Thread(target=node.run, name="loop", daemon=True)
    with client_session(router_endpoint) as session:
        last = Collector(session, "rf/t_post/cmd/safe", VelocityCommand)
        thread.start()
        poster = threading.Thread(target=lambda: [node.post(lambda: ran_on.append(threading.current_thread().name))
                                                  for _ in range(5)])
        poster.start()
        poster.join()
        assert wait_until(lambda: len(ran_on) == 5, 5)
        assert set(ran_on) == {"loop"}
        node.stop()
        thread.join(10)
        assert last.wait(1)[0].source == "last words"
        last.close()


def test_wildcard_puts_never_reach_a_handler_and_are_counted(router_endpoint):
    """Zenoh delivers a put on ``cmd/*``, ``rf/t_wild/**`` or ``**`` to a ``cmd/safe`` subscriber;
    the runtime drops it before the latest-value queue and counts it."""
    node = Node("echo", EchoSettings(connect=[router_endpoint], robot="t_wild"))
    seen: list[str] = []
    node.subscribe(node.keys.cmd_safe, VelocityCommand, lambda m: seen.append(m.source), queue="latest")
    thread = threading.Thread(target=node.run, daemon=True)
    thread.start()
    try:
        with client_session(router_endpoint) as session:
            assert wait_alive(session, "rf/t_wild/alive/echo")
            forged = ["rf/t_wild/cmd/*", "rf/t_wild/**", "**", "rf/*/cmd/safe", "rf/t_wild/cmd/$*fe"]
            for key in forged:
                put(session, key, VelocityCommand.zero(f"forged {key}"))
            session.delete("rf/t_wild/cmd/*")
            put(session, "rf/t_wild/cmd/safe", VelocityCommand.zero("legit"))
            assert wait_until(lambda: node.status().extra.get("wildcard_dropped", 0) == len(forged) + 1, 10)
            assert wait_until(lambda: seen == ["legit"], 10), seen
            assert node.status().received["cmd/safe"] == 1
    finally:
        node.stop()
        thread.join(10)


def test_a_wildcard_subscription_serves_concrete_keys_only():
    from riskfield.services.runtime.node import serves

    assert serves("rf/r/cmd/safe", "rf/r/cmd/safe")
    assert not serves("rf/r/cmd/safe", "rf/r/cmd/*") and not serves("rf/r/cmd/safe", "**")
    assert not serves("rf/r/cmd/safe", "rf/r/cmd/safe/x")
    assert serves("rf/r/**", "rf/r/state") and not serves("rf/r/**", "rf/r/**")
    assert not serves("rf/r/**", "rf/r/cmd/$*fe")
