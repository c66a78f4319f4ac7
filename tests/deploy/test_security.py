"""The shipped secure router config (deploy/zenoh/router-secure.json5) on loopback with real
Zenoh sessions: mutual TLS, user/password, and access control checked on the subscriber side
(a denied put is dropped silently, the publisher never learns of it)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
import zenoh

from riskfield.protocol import EsdfGrid, Keys, VelocityCommand
from riskfield.services.runtime.session import zenoh_config
from riskfield.services.runtime.settings import NodeSettings
from riskfield.testing import (
    Collector,
    ServiceProcess,
    free_port,
    open_when_ready,
    put,
    query_barrier,
    wait_matched,
    wait_until,
)

if TYPE_CHECKING:  # the fixture's type; conftest is not imported at run time
    from conftest import Secrets

REPO = Path(__file__).resolve().parents[2]
ROBOT = "t_sec"
KEYS = Keys(robot=ROBOT)


def client(secrets: Secrets, endpoint: str, user: str | None, cert: str | None, *, password: str | None = None,
           ca: Path | None = None, cert_dir: Path | None = None) -> zenoh.Session:
    """A client session built the way every riskfield node builds one (NodeSettings → config)."""
    certs = cert_dir or secrets.tls
    settings = NodeSettings(
        connect=[endpoint],
        tls_root_ca=ca or secrets.tls / "ca.pem",
        tls_cert=certs / f"{cert}.pem" if cert else None,
        tls_key=certs / f"{cert}.key" if cert else None,
        tls_mtls=cert is not None,
        user=user,
        password=password if password is not None else (secrets.passwords.get(user) if user else None),
    )
    return zenoh.open(zenoh_config(settings))


@contextlib.contextmanager
def session(*args, **kw) -> Iterator[zenoh.Session]:
    s = client(*args, **kw)
    try:
        yield s
    finally:
        s.close()


def refused(*args, **kw) -> bool:
    """True when the router refuses to open a session for these credentials."""
    try:
        s = client(*args, **kw)
    except zenoh.ZError:
        return True
    s.close()
    return False


def cmd(source: str) -> VelocityCommand:
    return VelocityCommand(linear=(0.3, 0.0, 0.0), angular=(0.0, 0.0, 0.1), source=source)


@contextlib.contextmanager
def secure_router(secrets: Secrets, tmp: Path, site: str, *, connect: str | None = None) -> Iterator[str]:
    """`riskfield run router` with the shipped secure config; yields its TLS endpoint."""
    endpoint = f"tls/localhost:{free_port()}"
    args = ["--set", f"zenoh_config={secrets.router_config(site, tmp)}", "--robot", ROBOT]
    env = {}
    if connect:
        args += ["--connect", connect]
        env = {"RISKFIELD_USER": "router", "RISKFIELD_PASSWORD": secrets.passwords["router"]}
    with ServiceProcess("router", endpoint, args, env=env) as proc:
        # Up when the node loop runs (a router dialling another returns from open only once
        # linked) and a legitimate client gets a session; bounded, the process may have failed.
        def up() -> bool:
            assert proc.alive(), proc.output
            return " up as router" in proc.output and not refused(secrets, endpoint, "limo", "limo")

        assert wait_until(up, timeout_s=20, period_s=0.2), proc.output
        yield endpoint
        assert proc.stop() == 0, proc.output


@pytest.fixture(scope="module")
def server(secrets: Secrets, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with secure_router(secrets, tmp_path_factory.mktemp("server"), "server") as endpoint:
        yield endpoint


def deliver(publisher: zenoh.Session, key: str, msg, collector: Collector, marker_key: str, marker) -> None:
    """Put ``msg`` on ``key``, then an allowed ``marker``; wait until the marker arrives. Puts of
    one session reach a subscriber in order, so anything allowed before the marker is in by then."""
    put(publisher, key, msg)
    put(publisher, marker_key, marker)
    collector.wait(1, timeout_s=5.0)


def sources(collector: Collector) -> list[str]:
    return [m.source for m in collector.items]


# -- authentication ------------------------------------------------------------------------------


def test_legitimate_client_over_mutual_tls_exchanges_data(secrets: Secrets, server: str) -> None:
    with session(secrets, server, "limo", "limo") as limo, session(secrets, server, "safety-filter",
                                                                      "safety-filter") as filt:
        got = Collector(limo, KEYS.cmd_safe, VelocityCommand)
        assert wait_matched(filt, KEYS.cmd_safe)
        put(filt, KEYS.cmd_safe, cmd("filter"))
        assert [m.source for m in got.wait(1)] == ["filter"]
        got.close()


def test_client_without_credentials_is_refused(secrets: Secrets, server: str) -> None:
    assert refused(secrets, server, None, "limo")


def test_wrong_password_and_unknown_user_are_refused(secrets: Secrets, server: str) -> None:
    assert refused(secrets, server, "teleop", "teleop", password="not-the-password")
    assert refused(secrets, server, "intruder", "teleop", password="guess")


def test_certificate_from_another_ca_is_refused(secrets: Secrets, server: str) -> None:
    # Right user and password, but the client certificate was signed by a foreign CA.
    assert refused(secrets, server, "safety-filter", "safety-filter", cert_dir=secrets.foreign,
                   ca=secrets.tls / "ca.pem")


def test_client_without_certificate_is_refused_by_mutual_tls(secrets: Secrets, server: str) -> None:
    assert refused(secrets, server, "safety-filter", None)


def test_client_that_does_not_trust_the_router_refuses_it(secrets: Secrets, server: str) -> None:
    # The client trusts only the foreign CA: the router's certificate fails verification.
    assert refused(secrets, server, "safety-filter", "safety-filter", cert_dir=secrets.foreign,
                   ca=secrets.foreign / "ca.pem")


def test_plain_tcp_is_not_served(secrets: Secrets, server: str) -> None:
    port = server.rsplit(":", 1)[1]
    settings = NodeSettings(connect=[f"tcp/127.0.0.1:{port}"], user="limo", password=secrets.passwords["limo"])
    with pytest.raises(zenoh.ZError):
        zenoh.open(zenoh_config(settings)).close()


# -- access control ------------------------------------------------------------------------------


def test_teleop_cmd_safe_never_reaches_a_subscriber(secrets: Secrets, server: str) -> None:
    with session(secrets, server, "limo", "limo") as limo, session(secrets, server, "teleop", "teleop") as tele:
        safe = Collector(limo, KEYS.cmd_safe, VelocityCommand)
        ref = Collector(limo, KEYS.cmd_ref, VelocityCommand)
        assert wait_matched(tele, KEYS.cmd_safe) and wait_matched(tele, KEYS.cmd_ref)
        for _ in range(3):
            deliver(tele, KEYS.cmd_safe, cmd("teleop-forged"), ref, KEYS.cmd_ref, cmd("teleop"))
        assert sources(safe) == []
        assert set(sources(ref)) == {"teleop"}  # the same session's allowed key got through
        safe.close()
        ref.close()


def test_only_the_filter_publishes_cmd_safe_and_not_operator_keys(secrets: Secrets, server: str) -> None:
    with (session(secrets, server, "limo", "limo") as limo,
          session(secrets, server, "safety-filter", "safety-filter") as filt):
        safe = Collector(limo, KEYS.cmd_safe, VelocityCommand)
        ref = Collector(limo, KEYS.cmd_ref, VelocityCommand)
        goal = Collector(limo, KEYS.nav_goal)
        assert all(wait_matched(filt, k) for k in (KEYS.cmd_ref, KEYS.nav_goal, KEYS.cmd_safe))
        put(filt, KEYS.cmd_ref, cmd("filter-ref"))
        put(filt, KEYS.nav_goal, b"\x80")
        deliver(filt, KEYS.cmd_safe, cmd("filter"), safe, KEYS.cmd_safe, cmd("filter"))
        assert sources(ref) == [] and goal.items == []
        assert sources(safe) == ["filter", "filter"]
        for c in (safe, ref, goal):
            c.close()


def test_data_services_may_not_publish_guarded_keys(secrets: Secrets, server: str) -> None:
    with session(secrets, server, "limo", "limo") as limo, session(secrets, server, "mapping", "mapping") as mapping:
        guarded = [Collector(limo, KEYS.key(k), VelocityCommand) for k in ("cmd/safe", "cmd/ref")]
        state = Collector(limo, KEYS.key("status/probe"))
        assert all(wait_matched(mapping, k) for k in (KEYS.cmd_safe, KEYS.cmd_ref, KEYS.key("status/probe")))
        put(mapping, KEYS.cmd_safe, cmd("mapping"))
        put(mapping, KEYS.cmd_ref, cmd("mapping"))
        deliver(mapping, KEYS.risk_config, b"\x80", state, KEYS.key("status/probe"), b"ok")
        assert all(c.items == [] for c in guarded)
        assert state.items == [b"ok"]


def test_every_client_may_subscribe_to_the_esdf_but_a_roleless_one_may_not_publish(
        secrets: Secrets, server: str) -> None:
    import numpy as np

    grid = EsdfGrid(origin=(0.0, 0.0, 0.0), voxel_size=0.1, distance=np.ones((4, 4, 1), np.float32),
                    risk_group=np.zeros((4, 4, 1), np.uint8), groups=["high", "mid", "low"], max_distance=2.0,
                    unknown_is_occupied=False)
    with (session(secrets, server, "planner", "planner") as planner,
          session(secrets, server, "mapping", "mapping") as mapping,
          session(secrets, server, "limo", "limo") as limo):
        esdf = Collector(planner, KEYS.esdf, EsdfGrid)
        at_limo = Collector(limo, KEYS.esdf, EsdfGrid)
        assert wait_matched(planner, KEYS.esdf) and wait_matched(mapping, KEYS.esdf)
        put(planner, KEYS.esdf, grid.model_copy(update={"max_distance": 9.0}))  # forged: denied
        put(mapping, KEYS.esdf, grid)
        assert esdf.wait(1)[0].voxel_size == pytest.approx(0.1)
        at_limo.wait(1)
        assert query_barrier(planner, limo)  # the forged grid, had it passed, is in by now
        assert [g.max_distance for g in at_limo.items] == [2.0]


def test_router_role_needs_a_router_certificate(secrets: Secrets, server: str) -> None:
    """The routers subject is user ``router`` AND a router-* certificate: the password alone
    (a leaked one, used with a node's certificate) gives no right to publish cmd/safe."""
    with (session(secrets, server, "limo", "limo") as limo,
          session(secrets, server, "router", "teleop") as impostor,
          session(secrets, server, "router", "router-robot") as router):
        safe = Collector(limo, KEYS.cmd_safe, VelocityCommand)
        assert wait_matched(impostor, KEYS.cmd_safe) and wait_matched(router, KEYS.cmd_safe)
        put(impostor, KEYS.cmd_safe, cmd("impostor"))
        deliver(router, KEYS.cmd_safe, cmd("router"), safe, KEYS.cmd_safe, cmd("router"))
        assert query_barrier(impostor, limo)  # the impostor's put, had it passed, is in by now
        assert sources(safe) == ["router", "router"]


# -- two sites ---------------------------------------------------------------------------------


@pytest.mark.slow  # a second router process meshing with the first
def test_two_sites_mesh_over_mutual_tls_and_each_router_enforces_roles(
        secrets: Secrets, server: str, tmp_path: Path) -> None:
    """The robot site's router dials the server's with its router certificate and the router
    user: the filter's cmd/safe on the robot side reaches a subscriber at the server site, an
    operator's forged cmd/safe on the robot side reaches neither site."""
    with secure_router(secrets, tmp_path, "robot", connect=server) as robot_site:
        with (session(secrets, server, "planner", "planner") as remote,
              session(secrets, robot_site, "limo", "limo") as local,
              session(secrets, robot_site, "safety-filter", "safety-filter") as filt,
              session(secrets, robot_site, "teleop", "teleop") as tele):
            at_server = Collector(remote, KEYS.cmd_safe, VelocityCommand)
            at_robot = Collector(local, KEYS.cmd_safe, VelocityCommand)
            # The routers link asynchronously: publish until the far subscriber hears it.
            assert wait_until(lambda: (put(filt, KEYS.cmd_safe, cmd("filter")), bool(at_server.items))[1],
                              timeout_s=15, period_s=0.2)
            # The teleop's allowed cmd/ref, put after its forged cmd/safe, marks when the latter
            # would have arrived at each site (one session's puts travel its links in order).
            ref_server = Collector(remote, KEYS.cmd_ref, VelocityCommand)
            ref_robot = Collector(local, KEYS.cmd_ref, VelocityCommand)
            assert wait_until(lambda: (put(tele, KEYS.cmd_ref, cmd("probe")),
                                       bool(ref_server.items) and bool(ref_robot.items))[1], timeout_s=15, period_s=0.2)
            assert wait_matched(tele, KEYS.cmd_safe)
            at_server.clear()
            at_robot.clear()
            ref_server.clear()
            ref_robot.clear()
            put(tele, KEYS.cmd_safe, cmd("teleop-forged"))
            put(tele, KEYS.cmd_ref, cmd("teleop"))
            put(filt, KEYS.cmd_safe, cmd("filter"))
            for c in (at_server, at_robot, ref_server, ref_robot):
                c.wait(1)
            assert set(sources(at_server)) == {"filter"}
            assert set(sources(at_robot)) == {"filter"}
            for c in (at_server, at_robot, ref_server, ref_robot):
                c.close()


@pytest.mark.slow  # a second router process and a 3 s absence window
def test_robot_router_with_a_foreign_certificate_cannot_join(secrets: Secrets, server: str, tmp_path: Path) -> None:
    """A router whose certificate another CA signed is refused by the server's router."""
    cfg = secrets.router_config("robot", tmp_path)
    site = cfg.parent
    (site / "tls" / "router.pem").write_bytes((secrets.foreign / "router-robot.pem").read_bytes())
    (site / "tls" / "router.key").write_bytes((secrets.foreign / "router-robot.key").read_bytes())
    # It trusts both CAs, so it would accept the server and its own foreign-signed clients:
    # only the server's verification of the rogue's certificate stands in the way.
    bundle = (secrets.tls / "ca.pem").read_bytes() + (secrets.foreign / "ca.pem").read_bytes()
    (site / "tls" / "ca.pem").write_bytes(bundle)
    endpoint = f"tls/localhost:{free_port()}"
    env = {"RISKFIELD_USER": "router", "RISKFIELD_PASSWORD": secrets.passwords["router"]}
    with ServiceProcess("router", endpoint, ["--set", f"zenoh_config={cfg}", "--connect", server], env=env) as proc:
        with session(secrets, server, "planner", "planner") as remote:
            at_server = Collector(remote, KEYS.cmd_safe, VelocityCommand)
            # Local clients of the rogue router use its (foreign) CA.
            filt = open_when_ready(lambda: client(secrets, endpoint, "safety-filter", "safety-filter",
                                                  cert_dir=secrets.foreign, ca=secrets.foreign / "ca.pem"), alive=proc)
            try:
                # The claim is an absence over time: while the rogue router retries its link (3 s of
                # scenario), the server's subscriber never becomes reachable from its side.
                assert not wait_matched(filt, KEYS.cmd_safe, timeout_s=3.0), proc.output
                put(filt, KEYS.cmd_safe, cmd("rogue"))
            finally:
                filt.close()
            assert at_server.items == []
            at_server.close()


# -- the client configs shipped for external tools ------------------------------------------------


def test_shipped_secure_client_config_subscribes_to_the_esdf(secrets: Secrets, server: str, tmp_path: Path) -> None:
    import json

    text = (REPO / "deploy" / "zenoh" / "client-secure.json5").read_text()
    cfg_file = tmp_path / "client.json5"
    cfg_file.write_text(text.replace("/etc/riskfield/tls/node.", str(secrets.tls / "planner."))
                        .replace("/etc/riskfield/tls/", f"{secrets.tls}/"))
    cfg = zenoh.Config.from_file(str(cfg_file))
    cfg.insert_json5("connect/endpoints", json.dumps([server]))
    cfg.insert_json5("transport/auth/usrpwd/password", json.dumps(secrets.passwords["planner"]))
    with zenoh.open(cfg) as planner, session(secrets, server, "mapping", "mapping") as mapping:
        got = Collector(planner, KEYS.esdf)
        assert wait_matched(mapping, KEYS.esdf)
        put(mapping, KEYS.esdf, b"esdf-bytes")
        assert got.wait(1) == [b"esdf-bytes"]
        got.close()
    # The placeholder password of the shipped file is refused.
    with pytest.raises(zenoh.ZError):
        cfg = zenoh.Config.from_file(str(cfg_file))
        cfg.insert_json5("connect/endpoints", json.dumps([server]))
        zenoh.open(cfg).close()


def test_shipped_plain_router_and_client_configs_work_together(tmp_path: Path) -> None:
    import json

    port = free_port()
    router_cfg = str(REPO / "deploy" / "zenoh" / "router.json5")
    with ServiceProcess("router", f"tcp/127.0.0.1:{port}", ["--set", f"zenoh_config={router_cfg}"]) as proc:
        cfg = zenoh.Config.from_file(str(REPO / "deploy" / "zenoh" / "client.json5"))
        cfg.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        with open_when_ready(lambda: zenoh.open(cfg), alive=proc) as s:
            got = Collector(s, KEYS.esdf)
            assert wait_matched(s, KEYS.esdf)
            put(s, KEYS.esdf, b"x")
            assert got.wait(1) == [b"x"]
            got.close()
