"""The secure router config, generated from the key declaration (protocol/keys.py ROUTES, ROLES;
`riskfield acl`), on loopback with real Zenoh sessions: mutual TLS, user/password, and access
control checked on the subscriber side (a denied put is dropped silently, the publisher never
learns of it). Every identity is per robot, ``{robot}.{role}``."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
import zenoh

from riskfield.protocol import EsdfGrid, Keys, VelocityCommand
from riskfield.protocol.keys import READ_ALL, REF_SOURCES, ROLES, ROS_ROUTES, ROUTES, TOPICS
from riskfield.services.runtime.acl import identity, router_config
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
ROBOT, OTHER = "t_sec", "t_sec2"  # conftest.ROBOTS: the deployment's two robots
KEYS, OTHER_KEYS = Keys(robot=ROBOT), Keys(robot=OTHER)
TELEOP_REF, JOY_REF = KEYS.cmd_ref_of("keyboard"), KEYS.cmd_ref_of("joystick")  # REF_SOURCES
NOBODY = "nobody"  # conftest.NOBODY: valid credentials, no role


def me(role: str, robot: str = ROBOT) -> str:
    return identity(robot, role)


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
def session(secrets: Secrets, endpoint: str, user: str | None, cert: str | None = "", **kw) -> Iterator[zenoh.Session]:
    """A session as ``user`` with the certificate of the same name (or ``cert``)."""
    s = client(secrets, endpoint, user, user if cert == "" else cert, **kw)
    try:
        yield s
    finally:
        s.close()


def refused(secrets: Secrets, endpoint: str, user: str | None, cert: str | None, **kw) -> bool:
    """True when the router refuses to open a session for these credentials."""
    try:
        s = client(secrets, endpoint, user, cert, **kw)
    except zenoh.ZError:
        return True
    s.close()
    return False


def cmd(source: str) -> VelocityCommand:
    return VelocityCommand(linear=(0.3, 0.0, 0.0), angular=(0.0, 0.0, 0.1), source=source)


@contextlib.contextmanager
def secure_router(secrets: Secrets, tmp: Path, site: str, *, connect: str | None = None) -> Iterator[str]:
    """`riskfield run router` with the generated secure config; yields its TLS endpoint. ``site``:
    ``server``, or a robot id for that robot's router (which dials ``connect``)."""
    endpoint = f"tls/localhost:{free_port()}"
    args = ["--set", f"zenoh_config={secrets.router_config(site, tmp)}", "--robot", ROBOT]
    env = {}
    if connect:
        args += ["--connect", connect]
        env = {"RISKFIELD_USER": me("router", site), "RISKFIELD_PASSWORD": secrets.passwords[me("router", site)]}
    with ServiceProcess("router", endpoint, args, env=env) as proc:
        # Up when the node loop runs (a router dialling another returns from open only once
        # linked) and a legitimate client gets a session; bounded, the process may have failed.
        def up() -> bool:
            assert proc.alive(), proc.output
            return " up as router" in proc.output and not refused(secrets, endpoint, me("limo"), me("limo"))

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


@contextlib.contextmanager
def watcher(secrets: Secrets, endpoint: str, robot: str = ROBOT) -> Iterator[zenoh.Session]:
    """An operator's session (it reads every key of its robot) holding the operator's liveliness
    token, the mark ``barrier`` waits for."""
    with session(secrets, endpoint, me("operator", robot)) as s:
        token = s.liveliness().declare_token(Keys(robot=robot).alive("operator"))
        try:
            yield s
        finally:
            token.undeclare()


def _answered(s: zenoh.Session, robot: str) -> bool:
    key = Keys(robot=robot).alive("operator")
    return any(r.ok is not None for r in s.liveliness().get(key, timeout=2.0))


def barrier(sender: zenoh.Session, observer: zenoh.Session, robot: str = ROBOT) -> bool:
    """True once the router has handled everything ``sender`` sent before, and has sent on to
    ``observer`` whatever of it it let through. The router answers a liveliness query (which any
    session may make, tokens carry no data) after the messages before it on the same link: the
    sender's answer means its earlier puts were judged; the observer's, asked next, comes behind
    anything they were forwarded as. ``robot``'s operator token (``watcher``) must be declared."""
    return (wait_until(lambda: _answered(sender, robot), 10, period_s=0.05)
            and wait_until(lambda: _answered(observer, robot), 10, period_s=0.05))


def sources(collector: Collector) -> list[str]:
    return [m.source for m in collector.items]


# -- authentication ------------------------------------------------------------------------------


def test_legitimate_client_over_mutual_tls_exchanges_data(secrets: Secrets, server: str) -> None:
    with session(secrets, server, me("limo")) as limo, session(secrets, server, me("safety-filter")) as filt:
        got = Collector(limo, KEYS.cmd_safe, VelocityCommand)
        assert wait_matched(filt, KEYS.cmd_safe)
        put(filt, KEYS.cmd_safe, cmd("filter"))
        assert [m.source for m in got.wait(1)] == ["filter"]
        got.close()


def test_client_without_credentials_is_refused(secrets: Secrets, server: str) -> None:
    assert refused(secrets, server, None, me("limo"))


def test_wrong_password_and_unknown_user_are_refused(secrets: Secrets, server: str) -> None:
    assert refused(secrets, server, me("teleop"), me("teleop"), password="not-the-password")
    assert refused(secrets, server, "intruder", me("teleop"), password="guess")
    # Another robot's password for this robot's user name: identities do not share secrets.
    assert refused(secrets, server, me("limo"), me("limo"), password=secrets.passwords[me("limo", OTHER)])


def test_certificate_from_another_ca_is_refused(secrets: Secrets, server: str) -> None:
    # Right user and password, but the client certificate was signed by a foreign CA.
    assert refused(secrets, server, me("safety-filter"), me("safety-filter"), cert_dir=secrets.foreign,
                   ca=secrets.tls / "ca.pem")


def test_client_without_certificate_is_refused_by_mutual_tls(secrets: Secrets, server: str) -> None:
    assert refused(secrets, server, me("safety-filter"), None)


def test_client_that_does_not_trust_the_router_refuses_it(secrets: Secrets, server: str) -> None:
    # The client trusts only the foreign CA: the router's certificate fails verification.
    assert refused(secrets, server, me("safety-filter"), me("safety-filter"), cert_dir=secrets.foreign,
                   ca=secrets.foreign / "ca.pem")


def test_plain_tcp_is_not_served(secrets: Secrets, server: str) -> None:
    port = server.rsplit(":", 1)[1]
    settings = NodeSettings(connect=[f"tcp/127.0.0.1:{port}"], user=me("limo"), password=secrets.passwords[me("limo")])
    with pytest.raises(zenoh.ZError):
        zenoh.open(zenoh_config(settings)).close()


# -- access control ------------------------------------------------------------------------------


def test_teleop_cmd_safe_never_reaches_a_subscriber(secrets: Secrets, server: str) -> None:
    with watcher(secrets, server) as watch, session(secrets, server, me("teleop")) as tele:
        safe = Collector(watch, KEYS.cmd_safe, VelocityCommand)
        ref = Collector(watch, TELEOP_REF, VelocityCommand)
        assert wait_matched(tele, KEYS.cmd_safe) and wait_matched(tele, TELEOP_REF)
        for _ in range(3):
            deliver(tele, KEYS.cmd_safe, cmd("teleop-forged"), ref, TELEOP_REF, cmd("teleop"))
        assert sources(safe) == []
        assert set(sources(ref)) == {"teleop"}  # the same session's allowed key got through
        safe.close()
        ref.close()


@pytest.mark.parametrize("role", ["navigator", "teleop"])
def test_a_source_puts_only_its_own_reference_key(secrets: Secrets, server: str, role: str) -> None:
    """Priority follows the key, and the key follows the identity. The navigator (and the
    keyboard) may not put the joystick's cmd/ref/joystick, its lock, or the plain cmd/ref whose
    declared source the filter would trust; its own cmd/ref/<source> gets through."""
    own_key = KEYS.cmd_ref_of(REF_SOURCES[role][0])
    with watcher(secrets, server) as watch, session(secrets, server, me(role)) as src:
        others = [JOY_REF, KEYS.cmd_ref, KEYS.cmd_lock_of("joystick"), KEYS.cmd_lock, KEYS.cmd_ref_of("ros2/teleop")]
        forged = [Collector(watch, k) for k in others]
        own = Collector(watch, own_key, VelocityCommand)
        assert all(wait_matched(src, k) for k in others)
        for k in others:
            put(src, k, cmd("joystick"))
        deliver(src, own_key, cmd(role), own, own_key, cmd(role))  # after the forged ones, on the same link
        assert [c.items for c in forged] == [[]] * len(forged)
        assert set(sources(own)) == {role}
        for c in (*forged, own):
            c.close()


def test_only_the_filter_publishes_cmd_safe_and_not_operator_keys(secrets: Secrets, server: str) -> None:
    with watcher(secrets, server) as watch, session(secrets, server, me("safety-filter")) as filt:
        safe = Collector(watch, KEYS.cmd_safe, VelocityCommand)
        ref = Collector(watch, KEYS.cmd_ref, VelocityCommand)
        goal = Collector(watch, KEYS.nav_goal)
        assert all(wait_matched(filt, k) for k in (KEYS.cmd_ref, KEYS.nav_goal, KEYS.cmd_safe))
        put(filt, KEYS.cmd_ref, cmd("filter-ref"))
        put(filt, KEYS.nav_goal, b"\x80")
        deliver(filt, KEYS.cmd_safe, cmd("filter"), safe, KEYS.cmd_safe, cmd("filter"))
        assert sources(ref) == [] and goal.items == []
        assert sources(safe) == ["filter", "filter"]
        for c in (safe, ref, goal):
            c.close()


def test_data_services_may_not_publish_guarded_keys(secrets: Secrets, server: str) -> None:
    with watcher(secrets, server) as watch, session(secrets, server, me("mapping")) as mapping:
        guarded = [Collector(watch, KEYS.key(k), VelocityCommand) for k in ("cmd/safe", "cmd/ref")]
        state = Collector(watch, KEYS.status("mapping"))
        assert all(wait_matched(mapping, k) for k in (KEYS.cmd_safe, KEYS.cmd_ref, KEYS.status("mapping")))
        put(mapping, KEYS.cmd_safe, cmd("mapping"))
        put(mapping, KEYS.cmd_ref, cmd("mapping"))
        deliver(mapping, KEYS.risk_config, b"\x80", state, KEYS.status("mapping"), b"ok")
        assert all(c.items == [] for c in guarded)
        assert state.items == [b"ok"]


def _grid(max_distance: float) -> EsdfGrid:
    return EsdfGrid(origin=(0.0, 0.0, 0.0), voxel_size=0.1, distance=np.ones((4, 4, 1), np.float32),
                    risk_group=np.zeros((4, 4, 1), np.uint8), groups=["high", "mid", "low"],
                    max_distance=max_distance, unknown_is_occupied=False)


def test_a_planner_subscribes_to_the_esdf_but_may_not_publish_it(secrets: Secrets, server: str) -> None:
    with (session(secrets, server, me("planner")) as planner,
          session(secrets, server, me("mapping")) as mapping,
          watcher(secrets, server) as watch):
        esdf = Collector(planner, KEYS.esdf, EsdfGrid)
        at_watch = Collector(watch, KEYS.esdf, EsdfGrid)
        assert wait_matched(planner, KEYS.esdf) and wait_matched(mapping, KEYS.esdf)
        put(planner, KEYS.esdf, _grid(9.0))  # forged: denied
        put(mapping, KEYS.esdf, _grid(2.0))
        assert esdf.wait(1)[0].voxel_size == pytest.approx(0.1)
        at_watch.wait(1)
        assert barrier(planner, watch)  # the forged grid, had it passed, is in by now
        assert [g.max_distance for g in at_watch.items] == [2.0]


def test_a_session_receives_only_the_keys_its_role_consumes(secrets: Secrets, server: str) -> None:
    """Read what it consumes: the LIMO bridge's identity subscribes to cmd/ref and the ESDF in vain
    (the router does not send them), while the filter's receives both."""
    with (session(secrets, server, me("limo")) as limo,
          session(secrets, server, me("safety-filter")) as filt,
          session(secrets, server, me("joystick")) as joy,
          session(secrets, server, me("mapping")) as mapping,
          watcher(secrets, server)):
        at_limo = [Collector(limo, JOY_REF, VelocityCommand), Collector(limo, KEYS.esdf)]
        ref, esdf = Collector(filt, KEYS.cmd_ref_any, VelocityCommand), Collector(filt, KEYS.esdf)
        assert wait_matched(joy, JOY_REF) and wait_matched(mapping, KEYS.esdf)
        put(joy, JOY_REF, cmd("joystick"))
        put(mapping, KEYS.esdf, _grid(2.0))
        ref.wait(1)
        esdf.wait(1)
        assert barrier(filt, limo)  # what the router sent limo before, it has by now
        assert [c.items for c in at_limo] == [[], []]
        for c in (*at_limo, ref, esdf):
            c.close()


def test_router_role_needs_a_router_certificate(secrets: Secrets, server: str) -> None:
    """The robot router's subject is its user AND its certificate: the password alone (a leaked one,
    used with a node's certificate) gives no right to publish cmd/safe."""
    with (watcher(secrets, server) as watch,
          session(secrets, server, me("router"), me("teleop")) as impostor,
          session(secrets, server, me("router")) as router):
        safe = Collector(watch, KEYS.cmd_safe, VelocityCommand)
        assert wait_matched(impostor, KEYS.cmd_safe) and wait_matched(router, KEYS.cmd_safe)
        put(impostor, KEYS.cmd_safe, cmd("impostor"))
        deliver(router, KEYS.cmd_safe, cmd("router"), safe, KEYS.cmd_safe, cmd("router"))
        assert barrier(impostor, watch)  # the impostor's put, had it passed, is in by now
        assert sources(safe) == ["router", "router"]


# -- one identity per robot ------------------------------------------------------------------------

#: Each robot-side identity and the keys its role produces (what it would forge on another robot).
ROBOT_PRODUCERS = {role: [k for k, r in ROUTES.items() if role in r.producers and "*" not in k]
                   for role, spec in ROLES.items() if spec.site == "robot" and spec.service is not None}


@pytest.mark.parametrize("role", sorted(r for r, ks in ROBOT_PRODUCERS.items() if ks))
def test_a_robots_identity_cannot_put_another_robots_keys(secrets: Secrets, server: str, role: str) -> None:
    """The other robot's identity of the same role puts every key its role produces, on this robot's
    keys and then on its own: this robot's consumers (an operator reading everything) get none of
    the forged ones, while the other robot's get every one of the real ones."""
    produced = ROBOT_PRODUCERS[role]
    with (watcher(secrets, server) as victim,
          watcher(secrets, server, OTHER) as own,
          session(secrets, server, me(role, OTHER)) as attacker):
        forged = {k: Collector(victim, KEYS.key(k)) for k in produced}
        real = {k: Collector(own, OTHER_KEYS.key(k)) for k in produced}
        # Its puts on this robot's keys do leave it (it knows of their subscribers): the router refuses them.
        assert all(wait_matched(attacker, KEYS.key(k)) and wait_matched(attacker, OTHER_KEYS.key(k)) for k in produced)
        for k in produced:
            put(attacker, KEYS.key(k), cmd("forged"))
            attacker.delete(KEYS.key(k))
        for k in produced:
            put(attacker, OTHER_KEYS.key(k), cmd(role))
        assert wait_until(lambda: all(c.items for c in real.values()), 10), {k: len(c.items) for k, c in real.items()}
        assert barrier(attacker, victim)
        assert {k: len(c.items) for k, c in forged.items()} == dict.fromkeys(produced, 0)
        for c in (*forged.values(), *real.values()):
            c.close()


def test_a_robots_identity_cannot_read_another_robots_commands(secrets: Secrets, server: str) -> None:
    """The other robot's bridge subscribes to this robot's cmd/safe: the router never sends it the
    commands this robot's bridge receives."""
    with (session(secrets, server, me("safety-filter")) as filt,
          session(secrets, server, me("limo")) as limo,
          session(secrets, server, me("limo", OTHER)) as other_limo,
          watcher(secrets, server)):
        mine = Collector(limo, KEYS.cmd_safe, VelocityCommand)
        spy = Collector(other_limo, KEYS.cmd_safe, VelocityCommand)
        assert wait_matched(filt, KEYS.cmd_safe)
        put(filt, KEYS.cmd_safe, cmd("filter"))
        mine.wait(1)
        assert barrier(filt, other_limo)
        assert spy.items == []
        mine.close()
        spy.close()


# -- attacks: wildcard key expressions, swapped credentials, role-less liveliness -----------------

GUARDED = ("cmd/safe", "cmd/ref", "nav/goal", "config/risk")


def forge(publisher: zenoh.Session, keys: list[str]) -> None:
    for key in keys:
        put(publisher, key, cmd("forged"))
        publisher.delete(key)


@pytest.mark.parametrize(("role", "allowed", "forbidden"), [
    # teleop may put cmd/ref, never cmd/safe: not through cmd/*, the robot's ** or **.
    ("teleop", "cmd/ref/keyboard", [f"rf/{ROBOT}/cmd/*", f"rf/{ROBOT}/cmd/s$*", f"rf/{ROBOT}/**", "**",
                                    "rf/*/cmd/safe", "rf/**/cmd/safe", f"rf/{ROBOT}/*/safe", "rf/*/cmd/ref",
                                    f"rf/{ROBOT}/cmd/ref/*", f"rf/{ROBOT}/cmd/ref/**", "rf/*/cmd/ref/keyboard"]),
    # a data service reaches none of the four guarded keys.
    ("mapping", "map/esdf", [f"rf/{ROBOT}/cmd/*", f"rf/{ROBOT}/nav/*", f"rf/{ROBOT}/config/*", f"rf/{ROBOT}/**",
                             "**", f"rf/{ROBOT}/*/*", "rf/*/cmd/ref", "rf/*/nav/goal", "rf/*/config/risk"]),
])
def test_wildcard_puts_and_deletes_are_refused_by_the_router(secrets: Secrets, server: str, role: str,
                                                             allowed: str, forbidden: list[str]) -> None:
    """Zenoh delivers a put on a key expression to every subscriber it intersects; the ACL
    must refuse the wildcard itself. Raw subscribers (no riskfield runtime filter) see nothing."""
    with watcher(secrets, server) as watch, session(secrets, server, me(role)) as attacker:
        guarded = {k: Collector(watch, KEYS.key(k)) for k in GUARDED if k != allowed}
        own = Collector(watch, KEYS.key(allowed))
        assert all(wait_matched(attacker, KEYS.key(k)) for k in GUARDED)
        forge(attacker, forbidden)
        deliver(attacker, KEYS.key(allowed), cmd(role), own, KEYS.key(allowed), cmd(role))
        assert wait_until(lambda: len(own.items) == 2, 5)  # the same session's own key got through, twice
        assert {k: len(c.items) for k, c in guarded.items()} == dict.fromkeys(guarded, 0)
        for c in (*guarded.values(), own):
            c.close()


@pytest.mark.parametrize(("user", "cert"), [("teleop", "safety-filter"), ("safety-filter", "teleop"),
                                            ("safety-filter", "limo")])
def test_a_certificate_works_only_with_its_own_user(secrets: Secrets, server: str, user: str, cert: str) -> None:
    """Certificates are bound to users: a valid certificate of one node with another node's
    (right) password opens a session but gets no role, so it can put neither key."""
    with (watcher(secrets, server) as watch,
          session(secrets, server, me(user), me(cert)) as swapped,
          session(secrets, server, me("safety-filter")) as filt):
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
    """A role-less client (or another role, or another robot's filter) declaring alive/safety-filter
    would make a supervisor believe the filter runs; the router refuses the token."""
    with (watcher(secrets, server) as watch,
          session(secrets, server, NOBODY) as roleless,
          session(secrets, server, me("teleop")) as tele,
          session(secrets, server, me("safety-filter", OTHER)) as other_filter):
        tokens = [roleless.liveliness().declare_token(KEYS.alive("safety-filter")),
                  tele.liveliness().declare_token(KEYS.alive("safety-filter")),
                  other_filter.liveliness().declare_token(KEYS.alive("safety-filter")),
                  roleless.liveliness().declare_token(f"rf/{ROBOT}/alive/*")]
        # A token's declaration travels its session's link in order: once each session's later
        # query was answered, the router has seen (and refused) the tokens.
        assert all(barrier(s, watch) for s in (roleless, tele, other_filter))
        assert alive(watch, "safety-filter") == []
        with session(secrets, server, me("safety-filter")) as filt:
            token = filt.liveliness().declare_token(KEYS.alive("safety-filter"))
            assert wait_until(lambda: alive(watch, "safety-filter") == [KEYS.alive("safety-filter")], 10)
            token.undeclare()
        for t in tokens:
            t.undeclare()


def test_a_roleless_client_may_not_serve_the_esdf_query(secrets: Secrets, server: str) -> None:
    """Only mapping answers map/esdf/query: a forged queryable's replies never arrive."""
    with (session(secrets, server, NOBODY) as roleless,
          session(secrets, server, me("planner")) as planner,
          watcher(secrets, server) as watch):
        q = roleless.declare_queryable(KEYS.esdf_query, lambda query: query.reply(query.key_expr, b"forged"))
        assert barrier(roleless, watch)  # the declaration, had it passed, is known by now
        replies = [r for r in planner.get(KEYS.esdf_query, timeout=1.0) if r.ok is not None]
        assert replies == []
        q.undeclare()


# -- two sites ---------------------------------------------------------------------------------


@pytest.mark.slow  # a second router process meshing with the first
def test_two_sites_mesh_over_mutual_tls_and_each_router_enforces_roles(
        secrets: Secrets, server: str, tmp_path: Path) -> None:
    """The robot site's router dials the server's with its robot's router identity: the filter's
    cmd/safe on the robot side reaches the server site, an operator's forged cmd/safe on the robot
    side reaches neither site, and the server forwards to the robot only what the robot site needs."""
    with secure_router(secrets, tmp_path, ROBOT, connect=server) as robot_site:
        with (watcher(secrets, server) as remote,
              session(secrets, robot_site, me("limo")) as local,
              session(secrets, robot_site, me("safety-filter")) as filt,
              session(secrets, robot_site, me("teleop")) as tele,
              session(secrets, robot_site, me("operator")) as dashboard):
            at_server = Collector(remote, KEYS.cmd_safe, VelocityCommand)
            at_robot = Collector(local, KEYS.cmd_safe, VelocityCommand)
            # The routers link asynchronously: publish until the far subscriber hears it.
            assert wait_until(lambda: (put(filt, KEYS.cmd_safe, cmd("filter")), bool(at_server.items))[1],
                              timeout_s=15, period_s=0.2)
            # And the other way: the server's map reaches the robot's filter. The 3-D grid, which
            # only the server's planners consume, is not forwarded: a dashboard on the robot's router
            # (an operator reads every key) gets the 2-D map put after it, and never the 3-D one.
            with session(secrets, server, me("mapping")) as mapper:
                map_at_robot = Collector(filt, KEYS.esdf)
                grid3d, grid2d = Collector(dashboard, KEYS.esdf3d), Collector(dashboard, KEYS.esdf)
                assert wait_until(lambda: (put(mapper, KEYS.esdf, cmd("map")), bool(map_at_robot.items))[1],
                                  timeout_s=15, period_s=0.2)
                assert wait_matched(mapper, KEYS.esdf3d)  # the server's own subscriber (remote)
                grid2d.clear()
                put(mapper, KEYS.esdf3d, cmd("map3d"))
                put(mapper, KEYS.esdf, cmd("map"))
                grid2d.wait(1)
                assert grid3d.items == []
                for c in (map_at_robot, grid3d, grid2d):
                    c.close()
            # The teleop's allowed cmd/ref, put after its forged cmd/safe, marks when the latter
            # would have arrived at each site (one session's puts travel its links in order).
            ref_server = Collector(remote, TELEOP_REF, VelocityCommand)
            ref_robot = Collector(filt, KEYS.cmd_ref_any, VelocityCommand)
            assert wait_until(lambda: (put(tele, TELEOP_REF, cmd("probe")),
                                       bool(ref_server.items) and bool(ref_robot.items))[1], timeout_s=15, period_s=0.2)
            assert wait_matched(tele, KEYS.cmd_safe)
            for c in (at_server, at_robot, ref_server, ref_robot):
                c.clear()
            put(tele, KEYS.cmd_safe, cmd("teleop-forged"))
            put(tele, TELEOP_REF, cmd("teleop"))
            put(filt, KEYS.cmd_safe, cmd("filter"))
            for c in (at_server, at_robot, ref_server, ref_robot):
                c.wait(1)
            assert set(sources(at_server)) == {"filter"}
            assert set(sources(at_robot)) == {"filter"}
            for c in (at_server, at_robot, ref_server, ref_robot):
                c.close()


def test_a_robots_router_admits_only_its_own_robots_identities(secrets: Secrets, tmp_path: Path) -> None:
    """A robot's router holds its own robot's passwords only (``ROBOT.users.txt``): another robot's
    identity, with its valid certificate and password, gets no session there at all."""
    with secure_router(secrets, tmp_path, ROBOT) as robot_site:
        for role in ("safety-filter", "limo", "operator"):
            assert not refused(secrets, robot_site, me(role), me(role)), role
            assert refused(secrets, robot_site, me(role, OTHER), me(role, OTHER)), role


@pytest.mark.slow  # a second router process and a 3 s absence window
def test_robot_router_with_a_foreign_certificate_cannot_join(secrets: Secrets, server: str, tmp_path: Path) -> None:
    """A router whose certificate another CA signed is refused by the server's router."""
    cfg = secrets.router_config(ROBOT, tmp_path)
    site = cfg.parent
    (site / "tls" / "router.pem").write_bytes((secrets.foreign / f"{me('router')}.pem").read_bytes())
    (site / "tls" / "router.key").write_bytes((secrets.foreign / f"{me('router')}.key").read_bytes())
    # It trusts both CAs, so it would accept the server and its own foreign-signed clients:
    # only the server's verification of the rogue's certificate stands in the way.
    bundle = (secrets.tls / "ca.pem").read_bytes() + (secrets.foreign / "ca.pem").read_bytes()
    (site / "tls" / "ca.pem").write_bytes(bundle)
    endpoint = f"tls/localhost:{free_port()}"
    env = {"RISKFIELD_USER": me("router"), "RISKFIELD_PASSWORD": secrets.passwords[me("router")]}
    with ServiceProcess("router", endpoint, ["--set", f"zenoh_config={cfg}", "--connect", server], env=env) as proc:
        with watcher(secrets, server) as remote:
            at_server = Collector(remote, KEYS.cmd_safe, VelocityCommand)
            # Local clients of the rogue router use its (foreign) CA.
            filt = open_when_ready(lambda: client(secrets, endpoint, me("safety-filter"), me("safety-filter"),
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
    text = (REPO / "deploy" / "zenoh" / "client-secure.json5").read_text()
    cfg_file = tmp_path / "client.json5"
    cfg_file.write_text(text.replace("/etc/riskfield/tls/node.", str(secrets.tls / f"{me('planner')}."))
                        .replace("/etc/riskfield/tls/", f"{secrets.tls}/").replace('"limo1.planner"',
                                                                                   json.dumps(me("planner"))))
    cfg = zenoh.Config.from_file(str(cfg_file))
    cfg.insert_json5("connect/endpoints", json.dumps([server]))
    cfg.insert_json5("transport/auth/usrpwd/password", json.dumps(secrets.passwords[me("planner")]))
    with zenoh.open(cfg) as planner, session(secrets, server, me("mapping")) as mapping:
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


# -- the ACL is the declaration's (no router needed) -----------------------------------------------


def test_the_shipped_secure_router_config_is_generated_from_the_declaration() -> None:
    """deploy/zenoh/router-secure.json5 is `riskfield acl`'s output for the default robot: a hand
    edit, or a key added to protocol/keys.py without regenerating, fails here."""
    shipped = (REPO / "deploy" / "zenoh" / "router-secure.json5").read_text()
    assert shipped == router_config(["limo1"]), "run `riskfield acl -o deploy/zenoh/router-secure.json5`"


def _acl(robots: list[str]) -> dict:
    cfg = zenoh.Config.from_json5(router_config(robots))
    return json.loads(cfg.get_json("access_control"))


def _allowed(acl: dict, subject: str, message: str, key: str, flow: str = "ingress") -> bool:
    """Whether ``subject``'s policies (and the catch-all ``everyone``'s) allow ``message`` on
    ``key``, as Zenoh decides it: an allow rule's key expression must include the message's
    (default deny, no deny rules)."""
    rules = {r["id"]: r for r in acl["rules"]}
    ids = [rid for p in acl["policies"] if subject in p["subjects"] or "everyone" in p["subjects"]
           for rid in p["rules"]]
    return any(r["permission"] == "allow" and flow in r["flows"] and message in r["messages"]
               and any(zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in r["key_exprs"])
               for r in (rules[i] for i in ids))


def test_every_identity_has_exactly_the_rights_its_role_is_declared() -> None:
    """For two robots: each identity may put exactly its role's keys (and its status, its token) of
    its own robot, receive exactly what it consumes, and nothing through a wildcard."""
    acl = _acl([ROBOT, OTHER])
    assert acl["enabled"] and acl["default_permission"] == "deny"
    assert set(TOPICS) <= set(ROUTES)  # every key of the contract is declared
    for robot, keys, other in ((ROBOT, KEYS, OTHER_KEYS), (OTHER, OTHER_KEYS, KEYS)):
        concrete = [k for k in ROUTES if "*" not in k]
        every = {keys.key(k) for k in concrete} | {f"{robot}/{t}" for t in ROS_ROUTES}
        every |= {keys.status(s.service) for s in ROLES.values() if s.service}
        for role, spec in ROLES.items():
            who = identity(robot, role)
            puts = {keys.key(k) for k in concrete if role in ROUTES[k].producers and not k.endswith("/query")}
            puts |= {f"{robot}/{t}" for t, r in ROS_ROUTES.items() if role in r.producers}
            reads = {keys.key(k) for k in concrete if role in ROUTES[k].consumers and not k.endswith("/query")}
            reads |= {f"{robot}/{t}" for t, r in ROS_ROUTES.items() if role in r.consumers}
            if spec.service:
                puts.add(keys.status(spec.service))
                reads.add(keys.status(spec.service))
                assert _allowed(acl, who, "liveliness_token", keys.alive(spec.service))
            for key in sorted(every):
                assert _allowed(acl, who, "put", key) == (key in puts), (who, key)
                if role not in READ_ALL:
                    assert _allowed(acl, who, "put", key, "egress") == (key in reads), (who, "receives", key)
                # never another robot's
                other_key = key.replace(keys.root, other.root, 1).replace(f"{robot}/", f"{other.robot}/", 1)
                assert not _allowed(acl, who, "put", other_key), (who, other_key)
                assert not _allowed(acl, who, "put", other_key, "egress"), (who, "receives", other_key)
            assert not _allowed(acl, who, "liveliness_token", keys.alive("safety-filter")) or role == "safety-filter"
            for wild in ("**", f"rf/{robot}/**", f"rf/{robot}/cmd/*", "rf/*/cmd/*", f"{robot}/**",
                         f"rf/{robot}/alive/*"):
                for msg in ("put", "delete", "liveliness_token"):
                    assert not _allowed(acl, who, msg, wild), (who, msg, wild)
        assert _allowed(acl, identity(robot, "mapping"), "declare_queryable", keys.esdf_query)
        assert not any(_allowed(acl, identity(robot, r), "declare_queryable", keys.esdf_query)
                       for r in ROLES if r != "mapping")
    # a session in no subject but the catch-all is told the declarations and may ask who is alive:
    # it sends nothing else and receives no data
    assert _allowed(acl, NOBODY, "liveliness_query", KEYS.alive("safety-filter"))
    assert _allowed(acl, NOBODY, "declare_subscriber", KEYS.cmd_safe, "egress")
    for key in (KEYS.cmd_safe, KEYS.esdf, KEYS.esdf_query, KEYS.alive("safety-filter"), "**"):
        sends = ("put", "delete", "liveliness_token", "declare_subscriber", "declare_queryable", "query", "reply")
        assert not any(_allowed(acl, NOBODY, m, key) for m in sends), key
        assert not any(_allowed(acl, NOBODY, m, key, "egress") for m in ("put", "delete", "query", "reply")), key
    # certificates bound to users: one identity per subject, user name = certificate common name
    for s in acl["subjects"]:
        if s["id"] not in ("everyone", "router-server"):
            assert s["usernames"] == s["cert_common_names"] == [s["id"]], s


def test_the_routers_forward_only_what_the_other_site_consumes() -> None:
    """At the server's router, a robot's router may bring in what robot-site roles produce and
    server-site roles consume, and is sent what the server produces for the robot site; nothing of
    another robot, and not what only its own site uses."""
    acl = _acl([ROBOT, OTHER])
    router = identity(ROBOT, "router")
    server = "router-server"  # as the robot's router sees the server's

    def site(role: str) -> str:
        return ROLES[role].site

    for k, r in ROUTES.items():
        if "*" in k or k.endswith("/query"):
            continue
        # the operators' tools (READ_ALL) are at the server: everything the robot site makes goes up
        assert all(site(role) == "server" for role in READ_ALL)
        up = any(site(p) == "robot" for p in r.producers)
        down = any(site(p) == "server" for p in r.producers) and any(site(c) == "robot" for c in r.consumers)
        key = KEYS.key(k)
        assert _allowed(acl, router, "put", key) == up == _allowed(acl, server, "put", key, "egress"), k
        assert _allowed(acl, router, "put", key, "egress") == down == _allowed(acl, server, "put", key), k
        assert not _allowed(acl, router, "put", OTHER_KEYS.key(k)), k  # nothing of the other robot
        assert not _allowed(acl, router, "put", OTHER_KEYS.key(k), "egress"), k
    # the map goes down, the 3-D grid (server planners only) and the camera's depth do not
    assert _allowed(acl, router, "put", KEYS.esdf, "egress")
    assert not _allowed(acl, router, "put", KEYS.esdf3d, "egress")
    assert not _allowed(acl, router, "put", KEYS.camera_depth, "egress")
    assert _allowed(acl, router, "put", KEYS.cmd_safe) and _allowed(acl, router, "put", KEYS.state)


def test_riskfield_secrets_and_acl_commands(tmp_path: Path) -> None:
    """`riskfield secrets` makes every identity of the robots named, with passwords readable by
    their owner only and kept across runs, and the routers' config for them; `riskfield acl`
    prints the same config."""
    from typer.testing import CliRunner

    from riskfield import cli
    from riskfield.services.runtime.acl import identities

    runner = CliRunner()
    out = tmp_path / "secrets"
    args = ["secrets", "--robot", "r1", "--robot", "r2", "--no-certs", "-o", str(out)]
    assert runner.invoke(cli.app, args).exit_code == 0
    users = dict(line.split(":", 1) for line in (out / "users.txt").read_text().split())
    assert set(users) == set(identities(["r1", "r2"])) and len(set(users.values())) == len(users)
    for path in (out / "users.txt", *out.glob("*.env"), *out.glob("*.users.txt")):
        assert path.stat().st_mode & 0o777 == 0o600, path
    for robot in ("r1", "r2"):  # a robot router's dictionary: its own identities, none of the fleet's others
        mine = dict(line.split(":", 1) for line in (out / f"{robot}.users.txt").read_text().split())
        assert mine == {u: p for u, p in users.items() if u in identities([robot])}
    assert (out / "r2.limo.env").read_text() == f"RISKFIELD_USER=r2.limo\nRISKFIELD_PASSWORD={users['r2.limo']}\n"
    assert runner.invoke(cli.app, args).exit_code == 0  # again: the same passwords
    assert dict(line.split(":", 1) for line in (out / "users.txt").read_text().split()) == users
    acl = runner.invoke(cli.app, ["acl", "--robot", "r1", "--robot", "r2"])
    assert acl.exit_code == 0 and acl.stdout == (out / "router-secure.json5").read_text() == router_config(["r1", "r2"])
    bad = runner.invoke(cli.app, ["acl", "--robot", "r/1"])
    assert bad.exit_code == 2
