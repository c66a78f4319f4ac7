"""Every ``RISKFIELD_*`` variable the README, the docs, the compose files and their env files name
works when exported in the shell as they show: each node that starts in that shell accepts it
(the compose interpolation variables are no setting of any node, and known as such)."""

from __future__ import annotations

import json
import re
from functools import cache
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel, TypeAdapter
from pydantic_core import PydanticUndefined
from pydantic_settings import NoDecode

from riskfield.services.runtime import SERVICES, ServiceUnavailable, load_service
from riskfield.services.runtime.service import ServiceSpec, build_settings
from riskfield.services.runtime.settings import (
    ENV_PREFIX,
    NOT_SETTINGS,
    env_names,
    know_other_services,
)

ROOT = Path(__file__).resolve().parents[2]
VAR = re.compile(r"\bRISKFIELD_[A-Z0-9_]*[A-Z0-9]\b")
INTERPOLATED = re.compile(r"\$\{(RISKFIELD_[A-Z0-9_]+)")


def documents() -> list[Path]:
    return sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md"), ROOT / "docker-compose.yml",
                   *(ROOT / "deploy").glob("*.yml"), *(ROOT / "deploy" / "env").glob("*.env")])


def documented() -> list[str]:
    return sorted({v for p in documents() for v in VAR.findall(p.read_text())})


@cache
def loadable() -> dict[str, ServiceSpec]:
    out = {}
    for name in SERVICES:
        try:
            out[name] = load_service(name)
        except ServiceUnavailable:  # an extra not installed here: the nodes that load are enough
            continue
    return out


def _head(var: str) -> str:
    return var.partition("__")[0]


def _value(field: Any, tmp_path: Path) -> str:
    """A value the field accepts from the environment: its default, or a file for a path."""
    default = field.get_default(call_default_factory=True)
    if default is PydanticUndefined or default is None:
        empty = tmp_path / "empty.yaml"  # a config file (RISKFIELD_CONFIG) must exist and parse
        empty.write_text("{}\n")
        return str(empty)
    if isinstance(default, bool):
        return "true" if default else "false"
    if any(m is NoDecode for m in field.metadata):  # a comma-separated list (RISKFIELD_CONNECT)
        return ",".join(map(str, default))
    if isinstance(default, list | tuple | dict | BaseModel):  # pydantic-settings decodes JSON
        return json.dumps(TypeAdapter(field.annotation).dump_python(default, mode="json"))
    return str(default)


@pytest.fixture
def shell(monkeypatch):
    """A shell with no ``RISKFIELD_*`` variable but the one under test, and the other services'
    settings known, as ``riskfield run`` installs them before it builds a node's settings."""
    import os

    from riskfield.cli import every_service_settings

    for var in list(os.environ):
        if var.upper().startswith(ENV_PREFIX):
            monkeypatch.delenv(var)
    know_other_services(every_service_settings)
    yield monkeypatch
    know_other_services(None)


def test_the_documents_name_the_variables_this_test_is_about():
    names = documented()
    assert {"RISKFIELD_ROUTER_PORT", "RISKFIELD_ROBOT_ROUTER_PORT", "RISKFIELD_SERVER_NETWORK",
            "RISKFIELD_CHECKPOINTS_DIR", "RISKFIELD_CONNECT", "RISKFIELD_LIMO_PORT"} <= set(names)


def test_every_compose_interpolation_variable_is_declared_or_a_setting():
    """A variable compose substitutes is set in the operator's shell, which the nodes inherit."""
    owned = {var for spec in loadable().values() for var in env_names(spec.settings)}
    files = [ROOT / "docker-compose.yml", *(ROOT / "deploy").glob("*.yml")]
    interpolated = {v for p in files for v in INTERPOLATED.findall(p.read_text())}
    assert interpolated, "no ${RISKFIELD_*} in the compose files: the pattern is stale"
    stray = sorted(v for v in interpolated if v[len(ENV_PREFIX):] not in NOT_SETTINGS and v not in owned)
    assert not stray, f"compose interpolates {stray}: declare them in runtime.settings.NOT_SETTINGS"


@pytest.mark.parametrize("var", documented())
def test_a_documented_variable_exported_in_the_shell_starts_every_node(var, shell, tmp_path):
    """What ``run_service`` does at start before any I/O: load the service, build its settings
    from the environment. The owner of a setting gets a value it accepts; every other node
    must ignore it."""
    nodes = loadable()
    owners = {name: env_names(spec.settings)[_head(var)] for name, spec in nodes.items()
              if _head(var) in env_names(spec.settings)}
    compose = var[len(ENV_PREFIX):] in NOT_SETTINGS
    assert compose or owners, f"{var} is documented but no setting of any node here, nor in NOT_SETTINGS"
    assert not (compose and owners), f"{var} is both a compose variable and a setting of {sorted(owners)}"
    value = _value(next(iter(owners.values())), tmp_path) if owners else "x"
    shell.setenv(var, value)
    for spec in nodes.values():
        build_settings(spec)  # raises UnknownSetting for a variable no node owns
