"""The shipped secure router config (deploy/zenoh/router-secure.json5) on loopback with real
Zenoh sessions: mutual TLS, user/password, and access control checked on the subscriber side
(a denied put is dropped silently, the publisher never learns of it)."""

from __future__ import annotations

import contextlib
import threading
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


def barrier(sender: zenoh.Session, observer: zenoh.Session) -> bool:
    """``riskfield.testing.query_barrier`` through the one queryable the access control lets a
    client declare: ``observer`` must hold the mapping role (it serves map/esdf/query). True once
    a query of ``sender`` reached ``observer``: every put ``sender`` made before, had the router let
    it through, has reached ``observer``'s subscribers by then (one session's messages keep their
    order on a path)."""
    hits = threading.Event()
    queryable = observer.declare_queryable(KEYS.esdf_query, lambda _query: hits.set())
    try:
        return wait_until(lambda: (sender.get(KEYS.esdf_query, timeout=0.5), hits.is_set())[1], 10, period_s=0.05)
    finally:
        queryable.undeclare()


def observer(secrets: Secrets, server: str):
    """A session that watches what arrives and can be a barrier's receiver (the mapping role)."""
    return session(secrets, server, "mapping", "mapping")


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
        state = Collector(limo, KEYS.status("mapping"))
        assert all(wait_matched(mapping, k) for k in (KEYS.cmd_safe, KEYS.cmd_ref, KEYS.status("mapping")))
        put(mapping, KEYS.cmd_safe, cmd("mapping"))
        put(mapping, KEYS.cmd_ref, cmd("mapping"))
        deliver(mapping, KEYS.risk_config, b"\x80", state, KEYS.status("mapping"), b"ok")
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
          observer(secrets, server) as limo):
        esdf = Collector(planner, KEYS.esdf, EsdfGrid)
        at_limo = Collector(limo, KEYS.esdf, EsdfGrid)
        assert wait_matched(planner, KEYS.esdf) and wait_matched(mapping, KEYS.esdf)
        put(planner, KEYS.esdf, grid.model_copy(update={"max_distance": 9.0}))  # forged: denied
        put(mapping, KEYS.esdf, grid)
        assert esdf.wait(1)[0].voxel_size == pytest.approx(0.1)
        at_limo.wait(1)
        assert barrier(planner, limo)  # the forged grid, had it passed, is in by now
        assert [g.max_distance for g in at_limo.items] == [2.0]


def test_router_role_needs_a_router_certificate(secrets: Secrets, server: str) -> None:
    """The routers subject is user ``router`` AND a router-* certificate: the password alone
    (a leaked one, used with a node's certificate) gives no right to publish cmd/safe."""
    with (observer(secrets, server) as limo,
          session(secrets, server, "router", "teleop") as impostor,
          session(secrets, server, "router", "router-robot") as router):
        safe = Collector(limo, KEYS.cmd_safe, VelocityCommand)
        assert wait_matched(impostor, KEYS.cmd_safe) and wait_matched(router, KEYS.cmd_safe)
        put(impostor, KEYS.cmd_safe, cmd("impostor"))
        deliver(router, KEYS.cmd_safe, cmd("router"), safe, KEYS.cmd_safe, cmd("router"))
        assert barrier(impostor, limo)  # the impostor's put, had it passed, is in by now
        assert sources(safe) == ["router", "router"]


# -- attacks: wildcard key expressions, swapped credentials, role-less liveliness (issue 19) ------

GUARDED = ("cmd/safe", "cmd/ref", "nav/goal", "config/risk")


def forge(publisher: zenoh.Session, keys: list[str]) -> None:
    for key in keys:
        put(publisher, key, cmd("forged"))
        publisher.delete(key)


@pytest.mark.parametrize(("user", "allowed", "forbidden"), [
    # teleop may put cmd/ref, never cmd/safe: not through cmd/*, the robot's ** or **.
    ("teleop", "cmd/ref", [f"rf/{ROBOT}/cmd/*", f"rf/{ROBOT}/cmd/s$*", f"rf/{ROBOT}/**", "**", "rf/*/cmd/safe",
                           "rf/**/cmd/safe", f"rf/{ROBOT}/*/safe"]),
    # a data service reaches none of the four guarded keys.
    ("mapping", "map/esdf", [f"rf/{ROBOT}/cmd/*", f"rf/{ROBOT}/nav/*", f"rf/{ROBOT}/config/*", f"rf/{ROBOT}/**",
                             "**", f"rf/{ROBOT}/*/*", "rf/*/cmd/ref", "rf/*/nav/goal", "rf/*/config/risk"]),
])
def test_wildcard_puts_and_deletes_are_refused_by_the_router(secrets: Secrets, server: str, user: str,
                                                             allowed: str, forbidden: list[str]) -> None:
    """Zenoh delivers a put on a key expression to every subscriber it intersects; the ACL
    must refuse the wildcard itself. Raw subscribers (no riskfield runtime filter) see nothing."""
    with session(secrets, server, "limo", "limo") as limo, session(secrets, server, user, user) as attacker:
        guarded = {k: Collector(limo, KEYS.key(k)) for k in GUARDED if k != allowed}
        own = Collector(limo, KEYS.key(allowed))
        assert all(wait_matched(attacker, KEYS.key(k)) for k in GUARDED)
        forge(attacker, forbidden)
        deliver(attacker, KEYS.key(allowed), cmd(user), own, KEYS.key(allowed), cmd(user))
        assert wait_until(lambda: len(own.items) == 2, 5)  # the same session's own key got through, twice
        assert {k: len(c.items) for k, c in guarded.items()} == dict.fromkeys(guarded, 0)
        for c in (*guarded.values(), own):
            c.close()


@pytest.mark.parametrize(("user", "cert"), [("teleop", "safety-filter"), ("safety-filter", "teleop"),
                                            ("safety-filter", "limo")])
def test_a_certificate_works_only_with_its_own_user(secrets: Secrets, server: str, user: str, cert: str) -> None:
    """Certificates are bound to users: a valid certificate of one node with another node's
    (right) password opens a session but gets no role, so it can put neither key."""
    with (observer(secrets, server) as watch,
          session(secrets, server, user, cert) as swapped,
          session(secrets, server, "safety-filter", "safety-filter") as filt):
        safe = Collector(watch, KEYS.cmd_safe, VelocityCommand)
        ref = Collector(watch, KEYS.cmd_ref, VelocityCommand)
        assert wait_matched(swapped, KEYS.cmd_safe) and wait_matched(swapped, KEYS.cmd_ref)
        for _ in range(3):
            put(swapped, KEYS.cmd_safe, cmd("swapped"))
            put(swapped, KEYS.cmd_ref, cmd("swapped"))
        assert barrier(swapped, watch)  # the swapped puts, had they passed, are in by now
        assert wait_matched(filt, KEYS.cmd_safe)
        put(filt, KEYS.cmd_safe, cmd("filter"))  # the positive control: the filter's own identity
        safe.wait(1)
        assert sources(safe) == ["filter"] and sources(ref) == []
        safe.close()
        ref.close()


def alive(observer: zenoh.Session, service: str) -> list[str]:
    return [str(r.ok.key_expr) for r in observer.liveliness().get(KEYS.alive(service), timeout=2.0)
            if r.ok is not None]


def test_only_the_filter_may_declare_its_liveliness_token(secrets: Secrets, server: str) -> None:
    """A role-less client (or another role) declaring alive/safety-filter would make a
    supervisor believe the filter runs; the router refuses the token."""
    with (session(secrets, server, "limo", "limo") as limo,
          session(secrets, server, "planner", "planner") as roleless,
          session(secrets, server, "teleop", "teleop") as tele):
        tokens = [roleless.liveliness().declare_token(KEYS.alive("safety-filter")),
                  tele.liveliness().declare_token(KEYS.alive("safety-filter")),
                  roleless.liveliness().declare_token(f"rf/{ROBOT}/alive/*")]
        # A token's declaration travels its session's link in order: once a later query of each
        # session reached an observer, the router has seen (and refused) the tokens.
        with observer(secrets, server) as watch:
            assert barrier(roleless, watch) and barrier(tele, watch)
        assert alive(limo, "safety-filter") == []
        with session(secrets, server, "safety-filter", "safety-filter") as filt:
            token = filt.liveliness().declare_token(KEYS.alive("safety-filter"))
            assert wait_until(lambda: alive(limo, "safety-filter") == [KEYS.alive("safety-filter")], 10)
            token.undeclare()
        for t in tokens:
            t.undeclare()


def test_a_roleless_client_may_not_serve_the_esdf_query(secrets: Secrets, server: str) -> None:
    """Only mapping answers map/esdf/query: a forged queryable's replies never arrive."""
    with (session(secrets, server, "planner", "planner") as roleless,
          session(secrets, server, "limo", "limo") as limo):
        q = roleless.declare_queryable(KEYS.esdf_query, lambda query: query.reply(query.key_expr, b"forged"))
        with observer(secrets, server) as watch:
            assert barrier(roleless, watch)  # the declaration, had it passed, is known by now
            replies = [r for r in limo.get(KEYS.esdf_query, timeout=1.0) if r.ok is not None]
        assert replies == []
        q.undeclare()


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
            # And the other way: the server's map reaches the robot's side (the robot's router takes
            # the server's router, which it dialled, by its certificate: subject server-router).
            with session(secrets, server, "mapping", "mapping") as mapper:
                map_at_robot = Collector(local, KEYS.esdf)
                assert wait_until(lambda: (put(mapper, KEYS.esdf, cmd("map")), bool(map_at_robot.items))[1],
                                  timeout_s=15, period_s=0.2)
                map_at_robot.close()
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


# -- the shipped ACL covers the product's keys (no router needed) -----------------------------------


def _acl() -> dict:
    import json

    cfg = zenoh.Config.from_file(str(REPO / "deploy" / "zenoh" / "router-secure.json5"))
    return json.loads(cfg.get_json("access_control"))


def _allowed(acl: dict, subject: str, message: str, key: str) -> bool:
    """Whether ``subject``'s policies allow ingress ``message`` on ``key``, as Zenoh decides it:
    an allow rule's key expression must include the message's (default deny, no deny rules)."""
    rules = {r["id"]: r for r in acl["rules"]}
    ids = [rid for p in acl["policies"] if subject in p["subjects"] for rid in p["rules"]]
    return any(r["permission"] == "allow" and "ingress" in r.get("flows", ["ingress", "egress"])
               and message in r["messages"]
               and any(zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in r["key_exprs"])
               for r in (rules[i] for i in ids))


#: Who puts each key of the product (the wire contract, the additive keys, the ROS 2 bridge's).
PUTS = {
    "safety-filter": ["cmd/safe", "safety/status"],
    "mapping": ["map/esdf", "map/esdf3d", "map/objects"],
    "perception": ["perception/frame"],
    "simulator": ["camera/image", "camera/depth", "state", "state/relocalise", "sim/truth", "sim/actors"],
    "limo": ["state", "limo/diagnostics"],
    "mavlink": ["state"],
    "joystick": ["cmd/ref"],
    "teleop": ["cmd/ref"],
    "navigator": ["cmd/ref"],
    "operator": ["cmd/ref", "nav/goal", "config/risk", "sim/spawn"],
    "ros2-bridge": ["cmd/ref", "state"],
    "relay": ["relay/out", "relay/esdf"],
}
ROS_PUTS = {"ros2-bridge": ["cmd_vel", "riskfield/costmap", "diagnostics", "tf"],
            "zenoh-bridge-ros2dds": ["cmd_vel_smoothed", "odom", "tf", "tf_static"]}
SERVICE_OF = {"teleop": "keyboard"}  # the role whose node has another service name
ROUTER_SUBJECTS = ("routers", "server-router")  # the sites' routers: forward, no role of their own


def test_every_key_the_product_publishes_has_exactly_its_roles() -> None:
    from riskfield.protocol.keys import TOPICS

    acl = _acl()
    assert acl["enabled"] and acl["default_permission"] == "deny"
    keys = Keys(robot="limo1")
    published = {k for ks in PUTS.values() for k in ks}
    assert set(TOPICS) - {"map/esdf/query"} <= published  # every key of the contract has a publisher
    roles = [s["id"] for s in acl["subjects"] if s["id"] not in ("everyone", *ROUTER_SUBJECTS)]
    for role in roles:
        service = SERVICE_OF.get(role, role)
        own = {keys.key(k) for k in PUTS.get(role, [])} | ({keys.status(service)} if role in PUTS else set())
        own |= {f"limo1/{t}" for t in ROS_PUTS.get(role, [])}
        for key in sorted({keys.key(k) for k in published} | {keys.status(service)} | own):
            assert _allowed(acl, role, "put", key) == (key in own), (role, key)
        if role in PUTS:
            assert _allowed(acl, role, "liveliness_token", keys.alive(service))
            assert not _allowed(acl, role, "liveliness_token", keys.alive("safety-filter")) or role == "safety-filter"
        for wild in ("**", "rf/limo1/**", "rf/limo1/cmd/*", "rf/*/cmd/*", "limo1/**", "rf/limo1/alive/*"):
            for msg in ("put", "delete", "liveliness_token"):
                assert not _allowed(acl, role, msg, wild), (role, msg, wild)
    assert _allowed(acl, "mapping", "declare_queryable", keys.esdf_query)
    assert not any(_allowed(acl, r, "declare_queryable", keys.esdf_query) for r in roles if r != "mapping")
    # a user in no role (matched by "everyone" only) subscribes and queries, and publishes nothing
    assert _allowed(acl, "everyone", "declare_subscriber", "**") and _allowed(acl, "everyone", "query", "**")
    assert not any(_allowed(acl, "everyone", m, keys.cmd_safe) for m in ("put", "delete", "liveliness_token"))
    # certificates bound to users: one identity per subject, user name = certificate common name
    for s in acl["subjects"]:
        if s["id"] not in ("everyone", *ROUTER_SUBJECTS):
            assert s["usernames"] == s["cert_common_names"] == [s["id"]], s
    # The server's router, seen from the robot's (which dialled it: usrpwd authenticates only the
    # dialler, so that link has no user name), is known by its certificate alone; like the routers
    # subject it may only forward.
    server_router = next(s for s in acl["subjects"] if s["id"] == "server-router")
    assert server_router["cert_common_names"] == ["router-server"] and not server_router.get("usernames")
    assert [p["rules"] for p in acl["policies"] if "server-router" in p["subjects"]] == [["forward-router"]]
