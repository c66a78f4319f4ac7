"""deploy/robot/install.sh staged into a tmp root, then its systemd units executed the way
systemd would (EnvironmentFile lines, then ExecStart with %i) against a router elsewhere."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
import typer
import zenoh

from riskfield import cli
from riskfield.protocol import Keys, VelocityCommand
from riskfield.services.runtime import SERVICES
from riskfield.services.runtime.acl import make_secrets
from riskfield.services.runtime.service import EXTRAS
from riskfield.services.runtime.session import zenoh_config
from riskfield.services.runtime.settings import NodeSettings
from riskfield.testing import (
    Collector,
    ServiceProcess,
    client_session,
    free_port,
    open_when_ready,
    put,
    wait_alive,
    wait_until,
)

if TYPE_CHECKING:
    from conftest import Secrets

REPO = Path(__file__).resolve().parents[2]
INSTALL = REPO / "deploy" / "robot" / "install.sh"


def install(root: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run(["bash", str(INSTALL), "--root", str(root), "--no-pip", *args], capture_output=True,
                          text=True, timeout=60)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def unit_directives(path: Path) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        if "=" in line and not line.startswith(("#", "[")):
            key, value = line.split("=", 1)
            out.setdefault(key, []).append(value)
    return out


class Unit:
    """A staged unit run as systemd runs it; /etc/riskfield in file contents maps to the stage. Its
    drop-ins (``UNIT.d/*.conf``, the template's and the instance's) add directives; ``LoadCredential=``
    copies into the unit's credentials folder, which ``%d`` names (systemd.exec, "Credentials")."""

    def __init__(self, root: Path, unit: str, instance: str = ""):
        self.root = root
        units = root / "etc/systemd/system"
        self.directives = unit_directives(units / unit)
        named = unit.replace("@.", f"@{instance}.") if instance else unit
        for conf in sorted({*units.glob(f"{unit}.d/*.conf"), *units.glob(f"{named}.d/*.conf")}):
            for key, values in unit_directives(conf).items():
                self.directives.setdefault(key, []).extend(values)
        self.instance = instance
        self.proc: subprocess.Popen | None = None
        self.log: tempfile._TemporaryFileWrapper | None = None  # made when it runs (__enter__)
        # systemd's /run/credentials/UNIT, inside the stage (the test's tmp_path, removed with it)
        self.credentials = root / "run/credentials" / named
        self.credentials.mkdir(parents=True, exist_ok=True)

    def _staged(self, text: str) -> str:
        return (text.replace("/etc/riskfield", str(self.root / "etc/riskfield")).replace("%i", self.instance)
                .replace("%d", str(self.credentials)))

    def environment(self) -> dict[str, str]:
        """Environment= first, then each EnvironmentFile= over it (systemd's order); credentials loaded."""
        for spec in self.directives.get("LoadCredential", []):
            name, source = spec.split(":", 1)
            shutil.copyfile(self._staged(source), self.credentials / name)
            (self.credentials / name).chmod(0o400)
        env: dict[str, str] = {}
        for spec in self.directives.get("Environment", []):
            key, value = spec.split("=", 1)
            env[key] = self._staged(value)
        for spec in self.directives["EnvironmentFile"]:
            optional = spec.startswith("-")
            path = Path(self._staged(spec.lstrip("-")))
            if not path.exists():
                assert optional, f"{path} is required by the unit"
                continue
            for line in path.read_text().splitlines():
                if line and not line.startswith("#"):
                    key, value = line.split("=", 1)
                    env[key] = self._staged(value)
        return env

    def argv(self) -> list[str]:
        exec_start = self._staged(self.directives["ExecStart"][0]).split()
        assert exec_start[0] == "/opt/riskfield/venv/bin/riskfield"
        return [sys.executable, "-m", "riskfield", *exec_start[1:]]

    def __enter__(self) -> Unit:
        base = {k: v for k, v in os.environ.items() if not k.startswith("RISKFIELD_")}
        self.log = tempfile.NamedTemporaryFile(prefix="rf-unit-", suffix=".log", delete=False)
        self.proc = subprocess.Popen(self.argv(), env={**base, "PYTHONUNBUFFERED": "1", **self.environment()},
                                     stdout=self.log, stderr=subprocess.STDOUT)
        return self

    @property
    def output(self) -> str:
        return "" if self.log is None else Path(self.log.name).read_text(errors="replace")

    def stop(self) -> int:
        """What `systemctl stop` does: SIGTERM, then wait (the node exits 0)."""
        assert self.proc is not None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def __exit__(self, *exc: object) -> None:
        self.stop()
        if self.log is not None:
            self.log.close()
            with contextlib.suppress(OSError):
                os.unlink(self.log.name)


# -- the staged files ---------------------------------------------------------------------------


def test_install_stages_units_and_settings(tmp_path: Path) -> None:
    install(tmp_path, "--server", "tcp/10.0.0.2:7447", "--robot", "limo9")
    units = tmp_path / "etc/systemd/system"
    assert sorted(p.name for p in units.iterdir()) == ["riskfield-router.service", "riskfield@.service"]
    router = unit_directives(units / "riskfield-router.service")
    node = unit_directives(units / "riskfield@.service")
    assert router["ExecStart"] == ["/opt/riskfield/venv/bin/riskfield run router"]
    assert node["ExecStart"] == ["/opt/riskfield/venv/bin/riskfield run %i"]
    assert node["Restart"] == ["on-failure"] and "riskfield-router.service" in node["After"][0]
    assert node["RestartPreventExitStatus"] == ["2"] and node["StartLimitBurst"] == ["10"]
    assert router["Restart"] == ["on-failure"] and router["StartLimitIntervalSec"] == ["0"]
    assert "dialout" in node["SupplementaryGroups"][0] and "input" in node["SupplementaryGroups"][0]
    env = Unit(tmp_path, "riskfield@.service", "safety-filter").environment()
    assert env["RISKFIELD_CONNECT"] == "tcp/127.0.0.1:7447" and env["RISKFIELD_ROBOT"] == "limo9"
    # the filter keeps its risk configuration in the unit's state directory; no other node has the setting
    assert env["RISKFIELD_STATE_DIR"] == "/var/lib/riskfield/safety-filter"
    assert node["StateDirectory"] == ["riskfield/%i"]
    # every node a user of its own: no node reads another's password (environ) or key (credential)
    assert node["DynamicUser"] == ["yes"] and node["User"] == ["riskfield-%i"] and router["User"] == ["riskfield"]
    assert "RISKFIELD_STATE_DIR" not in Unit(tmp_path, "riskfield@.service", "limo").environment()
    renv = Unit(tmp_path, "riskfield-router.service").environment()
    assert renv["RISKFIELD_MODE"] == "router" and renv["RISKFIELD_CONNECT"] == "tcp/10.0.0.2:7447"
    assert renv["RISKFIELD_LISTEN"] == env["RISKFIELD_CONNECT"]
    for f in (tmp_path / "etc/riskfield").glob("*.env"):
        assert f.stat().st_mode & 0o077 == 0, f  # settings may hold passwords


def test_install_for_a_first_bring_up_runs_the_camera_and_a_dry_run_bridge(tmp_path: Path) -> None:
    install(tmp_path, "--server", "tcp/10.0.0.2:7447", "--camera", "/dev/video2", "--dry-run")
    env = Unit(tmp_path, "riskfield@.service", "limo").environment()
    assert env["RISKFIELD_DRY_RUN"] == "true" and env["RISKFIELD_CAMERA_SOURCE"] == "/dev/video2"
    node = unit_directives(tmp_path / "etc/systemd/system/riskfield@.service")
    assert "video" in node["SupplementaryGroups"][0].split()
    install(tmp_path, "--server", "tcp/10.0.0.2:7447")
    assert Unit(tmp_path, "riskfield@.service", "limo").environment()["RISKFIELD_DRY_RUN"] == "false"


def test_the_autopilot_link_listens_on_loopback_unless_told(tmp_path: Path) -> None:
    """The vehicle state the filter trusts comes over unauthenticated MAVLink: by default only this
    computer (mavlink-router, a companion link) can send it."""
    install(tmp_path, "--server", "tcp/10.0.0.2:7447", "--services", "safety-filter mavlink")
    assert Unit(tmp_path, "riskfield@.service", "mavlink").environment()[
        "RISKFIELD_MAVLINK_URL"] == "udpin:127.0.0.1:14550"
    install(tmp_path, "--server", "tcp/10.0.0.2:7447", "--services", "mavlink", "--mavlink-url", "/dev/ttyACM0")
    assert Unit(tmp_path, "riskfield@.service", "mavlink").environment()["RISKFIELD_MAVLINK_URL"] == "/dev/ttyACM0"


def test_each_node_gets_its_own_key_and_password_only(tmp_path: Path) -> None:
    """--secrets: a node's settings name no key; its drop-in loads its own key alone as a credential
    (systemd's copy for that unit), and its own password; the router's files are the router's.
    Installed again without secrets, no node loads a key."""
    deploy = tmp_path / "secrets"
    make_secrets(deploy, ["limo3"])
    services = ["limo", "joystick", "safety-filter"]
    install(tmp_path / "root", "--server", "tls/10.0.0.2:7447", "--robot", "limo3", "--services",
            " ".join(services), "--secrets", str(deploy))
    root, etc = tmp_path / "root", tmp_path / "root/etc/riskfield"
    assert not [f for f in etc.glob("*.env") if "TLS_KEY" in f.read_text()]
    seen = {}
    for s in services:
        unit = Unit(root, "riskfield@.service", s)
        assert unit.directives["LoadCredential"] == [f"tls.key:/etc/riskfield/tls/{s}.key"], s
        env = unit.environment()
        assert Path(env["RISKFIELD_TLS_KEY"]).read_bytes() == (etc / f"tls/{s}.key").read_bytes()
        assert env["RISKFIELD_USER"] == f"limo3.{s}" and (etc / f"tls/{s}.key").stat().st_mode & 0o077 == 0
        seen[s] = env["RISKFIELD_PASSWORD"]
        # with identities, the filter takes a source only from its own key (protocol.keys.REF_SOURCES)
        assert env.get("RISKFIELD_REF_PLAIN_KEY") == ("false" if s == "safety-filter" else None), s
    assert len(set(seen.values())) == len(services)
    assert (etc / "tls").stat().st_mode & 0o777 == 0o755  # the certificates are public, each key 0600
    install(tmp_path / "root", "--server", "tcp/10.0.0.2:7447", "--robot", "limo3", "--services", " ".join(services))
    assert not list((root / "etc/systemd/system").glob("riskfield@*.service.d/identity.conf"))
    assert "LoadCredential" not in Unit(root, "riskfield@.service", "limo").directives


@pytest.mark.parametrize("services", ["camera limo joystick safety-filter", "safety-filter mavlink"])
def test_unit_commands_parse_with_the_real_cli(tmp_path: Path, services: str) -> None:
    install(tmp_path, "--server", "tcp/10.0.0.2:7447", "--services", services)
    run = typer.main.get_command(cli.app).commands["run"]
    for name in ["router", *services.split()]:
        unit = Unit(tmp_path, "riskfield-router.service") if name == "router" else Unit(
            tmp_path, "riskfield@.service", name)
        ctx = run.make_context("run", unit.argv()[4:])
        assert ctx.params["service"] == name and name in SERVICES


def test_systemd_accepts_the_units(tmp_path: Path) -> None:
    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze is not installed")
    make_secrets(tmp_path / "secrets", ["limo9"])  # the identity drop-ins too
    install(tmp_path / "root", "--server", "tls/10.0.0.2:7447", "--robot", "limo9", "--secrets",
            str(tmp_path / "secrets"))
    proc = subprocess.run(["systemd-analyze", "verify", "--root", str(tmp_path / "root"),
                           "riskfield-router.service", "riskfield@safety-filter.service"],
                          capture_output=True, text=True, timeout=60)
    assert "Unknown" not in proc.stderr and "Invalid" not in proc.stderr, proc.stderr
    assert "riskfield@safety-filter.service.d" in subprocess.run(
        ["systemd-analyze", "cat-config", "--root", str(tmp_path / "root"),
         "systemd/system/riskfield@safety-filter.service"], capture_output=True, text=True, timeout=60).stdout


def test_install_refuses_bad_arguments(tmp_path: Path) -> None:
    assert install(tmp_path, check=False).returncode == 2  # no --server
    assert install(tmp_path, "--server", "10.0.0.2", check=False).returncode == 2
    assert install(tmp_path, "--server", "tcp/h:7447", "--services", "simulator", check=False).returncode == 2
    assert install(tmp_path, "--server", "tcp/h:7447", "--robot", "a/b", check=False).returncode == 2
    proc = install(tmp_path, "--server", "tcp/h:7447", "--secrets", str(tmp_path), check=False)
    assert proc.returncode == 2 and "tls/" in proc.stderr


# -- running against a router elsewhere ----------------------------------------------------------


@contextlib.contextmanager
def staged_robot(tmp_path: Path, server: str, robot: str, *extra: str) -> Iterator[Path]:
    listen = f"{'tls' if '--secrets' in extra else 'tcp'}/127.0.0.1:{free_port()}"
    install(tmp_path, "--server", server, "--robot", robot, "--services", "relay", "--listen", listen, *extra)
    yield tmp_path


@pytest.mark.slow  # two routers and a node as processes
def test_installed_units_bring_the_robot_up_against_a_router_elsewhere(tmp_path: Path, router_endpoint: str) -> None:
    """The robot's router starts even while the server's router is unreachable, its nodes work
    locally, and the server sees them once the link exists. (`relay` stands in for a bridge.)"""
    robot = "t_robot_install"
    keys = Keys(robot=robot)
    down = f"tcp/127.0.0.1:{free_port()}"  # nothing listens here yet: the "server" comes later
    with staged_robot(tmp_path, down, robot) as root:
        with Unit(root, "riskfield-router.service") as r, Unit(root, "riskfield@.service", "relay") as relay:
            local = Unit(root, "riskfield@.service", "relay").environment()["RISKFIELD_CONNECT"]
            assert wait_until(lambda: " up as router" in r.output, 20), r.output
            with client_session(local) as s:
                assert wait_alive(s, keys.alive("relay"), timeout_s=20), relay.output
            # The server comes up where the robot's router was told to dial: it links by itself.
            with ServiceProcess("router", down, ["--robot", robot]) as server:
                with client_session(down) as s:
                    assert wait_alive(s, keys.alive("relay"), timeout_s=30), (r.output, server.output)
                    out = Collector(s, keys.key("relay/out"), VelocityCommand)
                    cmd = VelocityCommand(linear=(0.2, 0, 0), angular=(0, 0, 0), source="server")
                    assert wait_until(lambda: (put(s, keys.key("relay/in"), cmd), bool(out.items))[1], 15)
                    out.close()
            assert r.stop() == 0 and relay.stop() == 0, (r.output, relay.output)


@pytest.mark.slow  # two TLS routers and a node as processes
def test_installed_secure_units_link_to_a_secure_server(tmp_path: Path, secrets: Secrets) -> None:
    """--secrets: the robot's router dials the server's over mutual TLS as its robot's router
    identity; its node authenticates with its own certificate and user."""
    robot = "t_robot_install_tls"
    keys = Keys(robot=robot)
    # The deployment's secrets as `riskfield secrets --robot ROBOT` lays them out.
    deploy = tmp_path / "secrets"
    make_secrets(deploy, [robot, "t_other_robot"])  # a fleet of two: the robot gets only its own passwords
    passwords = dict(line.split(":", 1) for line in (deploy / "users.txt").read_text().split())
    made = type(secrets)(root=deploy, foreign=secrets.foreign, passwords=passwords)  # conftest.Secrets
    server_cfg = made.router_config("server", tmp_path / "server")
    server = f"tls/localhost:{free_port()}"
    with ServiceProcess("router", server, ["--set", f"zenoh_config={server_cfg}", "--robot", robot]) as srv:
        with staged_robot(tmp_path / "root", server, robot, "--secrets", str(deploy)) as root:
            staged_cfg = root / "etc/riskfield/router.json5"
            users = root / "etc/riskfield/users.txt"
            assert users.stat().st_mode & 0o777 == 0o600
            assert {line.split(":")[0] for line in users.read_text().split()} == {
                u for u in passwords if u.startswith(f"{robot}.")}
            assert all((root / "etc/riskfield" / f).stat().st_mode & 0o777 == 0o600
                       for f in ("router.env", "relay.env", "tls/relay.key", "tls/router.key"))
            staged_cfg.write_text(staged_cfg.read_text().replace("/etc/riskfield", str(root / "etc/riskfield")))
            env = Unit(root, "riskfield@.service", "relay").environment()
            assert env["RISKFIELD_TLS_MTLS"] == "true" and env["RISKFIELD_CONNECT"].startswith("tls/")
            # its key reaches it as its own credential (the copy the relay node below reads)
            key = Path(env["RISKFIELD_TLS_KEY"])
            assert key.parent == root / "run/credentials/riskfield@relay.service"
            assert key.read_bytes() == (root / "etc/riskfield/tls/relay.key").read_bytes()
            with Unit(root, "riskfield-router.service") as r, Unit(root, "riskfield@.service", "relay") as relay:
                # An external planner's view from the server site (a role-less user may subscribe).
                planner = f"{robot}.planner"
                watcher = NodeSettings(connect=[server], tls_root_ca=made.tls / "ca.pem",
                                       tls_cert=made.tls / f"{planner}.pem", tls_key=made.tls / f"{planner}.key",
                                       tls_mtls=True, user=planner, password=passwords[planner])
                session = open_when_ready(lambda: zenoh.open(zenoh_config(watcher)), alive=srv)
                try:
                    assert wait_alive(session, keys.alive("relay"), timeout_s=30), (r.output, relay.output)
                finally:
                    session.close()
                # Its node loop runs (a router dialling another returns from open once linked),
                # so a stop is the clean one systemd does.
                assert wait_until(lambda: " up as router" in r.output, 20), r.output
                assert r.stop() == 0 and relay.stop() == 0, (r.output, relay.output)
    assert srv.proc is not None and srv.proc.returncode == 0, srv.output


# -- the robot image's install step -----------------------------------------------------------------

#: The robot-side modules: the safety filter and the hardware bridges (what `riskfield run` loads).
ROBOT_MODULES = ("riskfield.services.safety_filter.node", "riskfield.edge.limo.node", "riskfield.edge.joystick.node",
                 "riskfield.edge.mavlink.node")


def _build_context(dockerfile: Path, dest: Path, root: str = "/src") -> None:
    """Copy what the Dockerfile COPYs from the repository into its project folder ``root`` (the
    final stage's source, installed there; the dependencies come from the ``deps`` stage's
    layer, which ``pip install ".[robot]"`` stands for here) into ``dest``."""
    for line in dockerfile.read_text().splitlines():
        words = line.split()
        if words[:1] != ["COPY"] or any(w.startswith("--") for w in words):
            continue
        *sources, target = words[1:]
        if target.rstrip("/") != root and not target.startswith(root + "/"):
            continue
        for src in sources:
            rel = Path(src).name if target.endswith("/") else target[len(root) + 1:]
            to = dest / rel
            if (REPO / src).is_dir():
                shutil.copytree(REPO / src, to, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
            else:
                to.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(REPO / src, to)


@pytest.mark.slow
def test_robot_image_install_step_works_in_a_clean_venv_without_open3d_or_torch(tmp_path: Path) -> None:
    """deploy/Dockerfile.robot's install without Docker: the source it COPYs into /src, then
    `pip install ".[robot]"` (its deps stage and its project install) into a fresh venv. Every
    robot service loads from it, and neither open3d nor torch is installed or imported."""
    import venv

    context, env_dir = tmp_path / "src", tmp_path / "venv"
    try:
        _build_context(REPO / "deploy" / "Dockerfile.robot", context)
        assert (context / "pyproject.toml").is_file() and (context / "services").is_dir()
        venv.create(env_dir, with_pip=True)
        py = str(env_dir / "bin" / "python")
        # Wheels come from pip's configured index and cache; nothing is fetched by the product.
        proc = subprocess.run([py, "-m", "pip", "install", "-q", "--disable-pip-version-check", ".[robot]"],
                              cwd=context, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, proc.stderr[-3000:]
        robot_services = sorted(n for n, extra in EXTRAS.items() if extra == "robot")
        code = (
            "import importlib, importlib.util, json, sys\n"
            "from riskfield.services.runtime.service import load_service\n"
            f"for name in {robot_services!r}: load_service(name)\n"
            f"for mod in {ROBOT_MODULES!r}: importlib.import_module(mod)\n"
            "print(json.dumps({'imported': sorted(m for m in ('open3d', 'torch') if m in sys.modules),\n"
            "                  'installed': sorted(m for m in ('open3d', 'torch') if importlib.util.find_spec(m)),\n"
            "                  'file': importlib.import_module('riskfield').__file__}))\n"
        )
        out = subprocess.run([py, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                             env={k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")})
        assert out.returncode == 0, out.stderr[-3000:]
        report = json.loads(out.stdout.strip().splitlines()[-1])
        assert report["imported"] == [] and report["installed"] == [], report
        assert report["file"].startswith(str(env_dir)), report  # the installed copy, not this checkout
    finally:
        shutil.rmtree(tmp_path, ignore_errors=True)  # a venv is hundreds of MB
