"""docker-compose.yml, its security overlay and the Dockerfiles, checked without a Docker engine.

The compose files are resolved by Debian's ``docker-compose`` (v1) when it is installed —
``config`` validates against Compose's own schema, interpolates and merges env files — and
otherwise by a small loader here (YAML, ``${VAR:-default}``, env files) checked against a
structural schema. Every riskfield container's command is then parsed by the real CLI and
its environment and ``--set`` keys are built into the service's real settings class.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import jsonschema
import pytest
import typer
import yaml
import zenoh

from riskfield import cli
from riskfield.services.runtime import SERVICES
from riskfield.services.runtime.service import EXTRAS, ServiceUnavailable, build_settings, load_service
from riskfield.services.runtime.settings import parse_overrides

REPO = Path(__file__).resolve().parents[2]
COMPOSE = REPO / "docker-compose.yml"
SECURE = REPO / "deploy" / "compose.secure.yml"

PROFILES = {
    "sim": {"router", "simulator", "perception", "mapping", "safety-filter", "navigator"},
    "gpu": {"router", "perception-gpu", "mapping"},
    "robot": {"robot-router", "robot-safety-filter", "limo", "joystick"},
    "mavlink": {"robot-router", "robot-safety-filter", "mavlink"},
}
ROUTERS = {"router", "robot-router"}
ENV = {"RISKFIELD_SERVER": "tcp/10.0.0.2:7447", "RISKFIELD_ROBOT": "limo7"}


# -- loading ----------------------------------------------------------------------------------

_VAR = re.compile(r"\$\{(\w+)(?::?-([^}]*))?\}")


def _interpolate(value: Any, env: dict[str, str]) -> Any:
    if isinstance(value, str):
        return _VAR.sub(lambda m: env.get(m.group(1)) or (m.group(2) or ""), value)
    if isinstance(value, list):
        return [_interpolate(v, env) for v in value]
    if isinstance(value, dict):
        return {k: _interpolate(v, env) for k, v in value.items()}
    return value


def _read_env_file(path: Path) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            key, _, value = line.partition("=")
            out[key.strip()] = value.strip()
    return out


def _merge(base: dict, over: dict) -> dict:
    """Compose's override rules for the keys these files use: mappings merge, volumes merge
    by container path, scalars and lists (command, env_file) are replaced."""
    out = dict(base)
    for key, value in over.items():
        if key == "volumes" and key in out:
            by_target = {v.split(":")[1]: v for v in out[key]}
            by_target.update({v.split(":")[1]: v for v in value})
            out[key] = list(by_target.values())
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
        else:
            out[key] = value
    return out


#: Enough of the Compose specification to catch typos and misplaced keys in our files.
SCHEMA: dict[str, Any] = {
    "type": "object",
    "required": ["services"],
    "patternProperties": {"^x-": {}},
    "properties": {
        "services": {"type": "object", "additionalProperties": {"$ref": "#/$defs/service"}},
        "volumes": {"type": "object"},
    },
    "additionalProperties": False,
    "$defs": {
        "strings": {"type": "array", "items": {"type": "string"}},
        "service": {
            "type": "object",
            "additionalProperties": False,
            "properties": {
                "image": {"type": "string"},
                "build": {"type": "object", "required": ["context", "dockerfile"],
                          "properties": {"context": {"type": "string"}, "dockerfile": {"type": "string"}},
                          "additionalProperties": False},
                "command": {"$ref": "#/$defs/strings"},
                "profiles": {"$ref": "#/$defs/strings"},
                "environment": {"type": "object", "additionalProperties": {"type": ["string", "number", "boolean"]}},
                "env_file": {"$ref": "#/$defs/strings"},
                "volumes": {"$ref": "#/$defs/strings"},
                "ports": {"$ref": "#/$defs/strings"},
                "devices": {"$ref": "#/$defs/strings"},
                "device_cgroup_rules": {"$ref": "#/$defs/strings"},
                "group_add": {"$ref": "#/$defs/strings"},
                "depends_on": {"$ref": "#/$defs/strings"},
                "restart": {"enum": ["no", "always", "on-failure", "unless-stopped"]},
                "shm_size": {"type": "string"},
                "deploy": {"type": "object"},
            },
        },
    },
}


def _load_without_docker_compose(files: list[Path], env: dict[str, str]) -> dict[str, Any]:
    merged: dict[str, Any] = {"services": {}}
    for f in files:
        doc = yaml.safe_load(f.read_text())  # YAML merge keys (<<) resolve here
        jsonschema.validate(doc, SCHEMA)
        doc = _interpolate(doc, env)
        for name, svc in doc["services"].items():
            merged["services"][name] = _merge(merged["services"].get(name, {}), svc)
        merged.update({k: v for k, v in doc.items() if k != "services"})
    for svc in merged["services"].values():
        environment: dict[str, str] = {}
        for ef in svc.pop("env_file", []):
            environment.update(_read_env_file(REPO / ef if not os.path.isabs(ef) else Path(ef)))
        environment.update({k: str(v) for k, v in svc.get("environment", {}).items()})
        svc["environment"] = environment
    return merged


def _load_with_docker_compose(files: list[Path], env: dict[str, str]) -> dict[str, Any]:
    args = ["docker-compose", "--project-directory", str(REPO)]
    for f in files:
        args += ["-f", str(f)]
    proc = subprocess.run([*args, "config"], capture_output=True, text=True, timeout=60,
                          env={**os.environ, **env}, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    doc = yaml.safe_load(proc.stdout)
    for svc in doc["services"].values():
        svc["environment"] = {k: str(v) for k, v in (svc.get("environment") or {}).items()}
        if isinstance(svc.get("depends_on"), dict):
            svc["depends_on"] = list(svc["depends_on"])
    return doc


LOADERS = ["python"] + (["docker-compose"] if shutil.which("docker-compose") else [])


def load(loader: str, files: list[Path], env: dict[str, str]) -> dict[str, Any]:
    fn = _load_with_docker_compose if loader == "docker-compose" else _load_without_docker_compose
    return fn(files, env)


@pytest.fixture(scope="module", params=LOADERS)
def stack(request: pytest.FixtureRequest) -> dict[str, Any]:
    return load(request.param, [COMPOSE], ENV)["services"]


@pytest.fixture(scope="module")
def secure_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """A deployment's secrets made by the real scripts, outside the repository."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    root = tmp_path_factory.mktemp("secrets")
    subprocess.run(["bash", str(REPO / "deploy" / "make-certs.sh"), "-o", str(root / "certs")], check=True,
                   capture_output=True, timeout=60)
    subprocess.run(["bash", str(REPO / "deploy" / "make-users.sh"), "-o", str(root)], check=True,
                   capture_output=True, timeout=60)
    return {**ENV, "RISKFIELD_SERVER": "tls/10.0.0.2:7447", "RISKFIELD_SECRETS": str(root)}


@pytest.fixture(scope="module", params=LOADERS)
def secure_stack(request: pytest.FixtureRequest, secure_env: dict[str, str]) -> dict[str, Any]:
    return load(request.param, [COMPOSE, SECURE], secure_env)["services"]


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


# -- routers ----------------------------------------------------------------------------------


def test_routers_are_the_zenoh_image_with_the_project_config(stack: dict[str, Any]) -> None:
    for name in ROUTERS:
        svc = stack[name]
        assert re.fullmatch(r"eclipse/zenoh:\d+\.\d+\.\d+", svc["image"]), svc["image"]
        cmd = svc["command"]
        config_in_container = cmd[cmd.index("-c") + 1]
        mounts = {v.split(":")[1]: _host_path(v) for v in svc["volumes"]}
        host = mounts[config_in_container]
        assert host.parent == REPO / "deploy" / "zenoh" and host.is_file()
        zenoh.Config.from_file(str(host))  # zenoh itself accepts it
    # The robot's router dials the server's router given at deploy time.
    cmd = stack["robot-router"]["command"]
    assert cmd[cmd.index("-e") + 1] == ENV["RISKFIELD_SERVER"]


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
    assert set(nodes) == set().union(*PROFILES.values()) - ROUTERS
    checked = {name: _check_riskfield_container(name, svc, monkeypatch) for name, svc in nodes.items()}
    # The services that exist in this tree are fully checked; the report names the others.
    print("\n".join(f"{n}: {c}" for n, c in sorted(checked.items())))
    assert checked["robot-safety-filter"] == checked["safety-filter"]


def test_robot_containers_use_the_robot_image_and_need_only_the_robot_extra(stack: dict[str, Any]) -> None:
    for name in (PROFILES["robot"] | PROFILES["mavlink"]) - ROUTERS:
        svc = stack[name]
        assert svc["build"]["dockerfile"] == "deploy/Dockerfile.robot", name
        service = svc["command"][1]
        assert EXTRAS.get(service, "robot") == "robot", f"{service} needs [{EXTRAS[service]}], not in the robot image"
        assert svc["environment"]["RISKFIELD_CONNECT"] == "tcp/robot-router:7447"
    for name in PROFILES["sim"] - ROUTERS:
        assert stack[name]["build"]["dockerfile"] == "deploy/Dockerfile.cpu", name
        assert stack[name]["environment"]["RISKFIELD_CONNECT"] == "tcp/router:7447"


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
    joystick = stack["joystick"]
    assert any(v.split(":")[1] == "/dev/input" for v in joystick["volumes"])
    assert any(r.startswith("c 13:") for r in joystick["device_cgroup_rules"])
    mav = stack["mavlink"]
    port = mav["environment"]["RISKFIELD_MAVLINK_URL"].rsplit(":", 1)[1]
    assert any(str(p).endswith(f"{port}/udp") or str(p) == f"{port}:{port}/udp" for p in mav["ports"]) or any(
        isinstance(p, dict) and str(p.get("target")) == port and p.get("protocol") == "udp" for p in mav["ports"])


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
    filters = [s for s in secure_stack.values() if s.get("command", [""])[-1] == "safety-filter"]
    assert filters and all(s["environment"]["RISKFIELD_USER"] == "safety-filter" for s in filters)


def test_secure_routers_use_the_secure_config_and_its_files(secure_stack: dict[str, Any]) -> None:
    server = secure_stack["router"]
    mounts = {v.split(":")[1]: _host_path(v) for v in server["volumes"]}
    assert mounts["/etc/zenoh/router.json5"] == REPO / "deploy" / "zenoh" / "router-secure.json5"
    text = mounts["/etc/zenoh/router.json5"].read_text()
    for path in re.findall(r'"(/etc/riskfield/[^"]+)"', text):
        assert mounts[path].is_file(), path
    robot = secure_stack["robot-router"]
    cmd = robot["command"]
    assert cmd[:2] == ["run", "router"] and cmd[cmd.index("--connect") + 1] == "tls/10.0.0.2:7447"
    assert robot["environment"]["RISKFIELD_USER"] == "router"
    mounts = {v.split(":")[1]: _host_path(v) for v in robot["volumes"]}
    for path in re.findall(r'"(/etc/riskfield/[^"]+)"', text):
        assert mounts[path].is_file(), path
    cn = subprocess.run(["openssl", "x509", "-noout", "-subject", "-in", str(mounts["/etc/riskfield/tls/router.pem"])],
                        capture_output=True, text=True, check=True).stdout
    assert "router-robot" in cn


# -- Dockerfiles ------------------------------------------------------------------------------


def _instructions(path: Path) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with line continuations joined and comments dropped."""
    kept = [ln for ln in path.read_text().splitlines() if not ln.lstrip().startswith("#")]
    text = re.sub(r"\\\n", " ", "\n".join(kept))
    return [(ln.split(None, 1)[0].upper(), ln.split(None, 1)[1] if " " in ln.strip() else "")
            for ln in text.splitlines() if ln.strip()]


@pytest.mark.parametrize("role", ["cpu", "robot", "gpu"])
def test_dockerfile_structure(role: str) -> None:
    path = REPO / "deploy" / f"Dockerfile.{role}"
    ins = _instructions(path)
    kinds = [k for k, _ in ins]
    assert kinds[0] in ("ARG", "FROM") and "FROM" in kinds
    # Sources copied into the image exist; the build context is trimmed by a per-Dockerfile ignore file.
    for k, args in ins:
        if k == "COPY" and "--from" not in args:
            *sources, _ = args.split()
            for s in sources:
                assert (REPO / s).exists(), s
    ignore = (REPO / "deploy" / f"Dockerfile.{role}.dockerignore").read_text()
    assert ignore.splitlines()[1] == "**" or "**" in ignore.splitlines()
    # The final stage runs riskfield as an unprivileged user.
    final = kinds[len(kinds) - 1 - kinds[::-1].index("FROM"):]
    assert "USER" in final
    user_lines = [a for k, a in ins if k == "USER"]
    assert user_lines and user_lines[-1] != "root"
    assert ('ENTRYPOINT', '["riskfield"]') in ins
    # torch is never installed unpinned.
    for package in _pip_installed(ins):
        if re.match(r"torch(vision)?\b", package):
            assert "==" in package, package


def _pip_installed(ins: list[tuple[str, str]]) -> list[str]:
    """The requirement arguments of every `pip install` / `uv pip install` in RUN lines."""
    out = []
    for k, args in ins:
        if k != "RUN":
            continue
        for command in re.split(r"&&|;|\|\|", args):
            words = command.split()
            if "install" in words and "pip" in words[: words.index("install")]:
                out += [w.strip("\"'") for w in words[words.index("install") + 1:] if not w.startswith("-")]
    return out


def test_robot_image_has_only_the_robot_extra() -> None:
    ins = _instructions(REPO / "deploy" / "Dockerfile.robot")
    installs = [a for k, a in ins if k == "RUN" and "pip install" in a]
    assert installs and all('".[robot]"' in a for a in installs)
    text = " ".join(a for _, a in ins).lower()
    assert "open3d" not in text.replace("pip show open3d", "") and "torch" not in text.replace(
        "pip show open3d torch numba", "")
    assert next(a for k, a in ins if k == "FROM").startswith("${PYTHON_IMAGE}")
    assert "python:3.11-slim" in next(a for k, a in ins if k == "ARG" and a.startswith("PYTHON_IMAGE"))


def test_cpu_image_installs_all_but_no_torch() -> None:
    ins = _instructions(REPO / "deploy" / "Dockerfile.cpu")
    installs = [a for k, a in ins if k == "RUN" and "pip install" in a]
    assert any('".[all]"' in a for a in installs)
    assert not any("torch" in a for a in installs)
    apt = " ".join(a for k, a in ins if k == "RUN" and "apt-get install" in a)
    assert "libgomp1" in apt and "libusb-1.0-0" in apt


def test_gpu_image_builds_mast3r_slam_and_efficientvit_from_pinned_sources() -> None:
    ins = _instructions(REPO / "deploy" / "Dockerfile.gpu")
    args = dict(a.split("=", 1) for k, a in ins if k == "ARG" and "=" in a)
    assert args["CUDA_IMAGE"].startswith("nvidia/cuda:12.")
    assert args["TORCH_VERSION"].startswith("2.5.")
    assert re.fullmatch(r"[0-9a-f]{7,40}", args["MAST3R_SLAM_REF"])
    assert re.fullmatch(r"[0-9a-f]{7,40}", args["EFFICIENTVIT_REF"])
    runs = " ".join(a for k, a in ins if k == "RUN")
    assert "github.com/rmurai0610/MASt3R-SLAM" in runs and "github.com/mit-han-lab/efficientvit" in runs
    assert "princeton-vl/lietorch" in runs  # not the unrelated PyPI lietorch
    assert "--no-build-isolation -e ." in runs
    assert ("VOLUME", '["/checkpoints"]') in ins
    assert "torch==${TORCH_VERSION}" in _pip_installed(ins)
    assert not re.search(r"(wget|curl)\s+\S*(\.pth|\.pt|\.pkl)", runs), "checkpoints must come from the volume"


def test_pip_install_parsing_sees_unpinned_torch(tmp_path: Path) -> None:
    df = tmp_path / "Dockerfile"
    df.write_text('FROM x\n# pip install torch\nRUN apt-get update && \\\n    pip install -q numpy "torch>=2" \\\n'
                  '    && pip show torch\nRUN uv pip install --no-deps torchvision==0.20.1 lietorch\n')
    assert _pip_installed(_instructions(df)) == ["numpy", "torch>=2", "torchvision==0.20.1", "lietorch"]
