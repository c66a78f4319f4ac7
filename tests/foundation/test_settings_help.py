"""``riskfield run SERVICE --help``: every setting with a readable type, its default and a
description; an unknown service name gets the nearest known one."""

from __future__ import annotations

import typing
from functools import cache
from pathlib import Path
from typing import Annotated, Literal

import pytest
from pydantic import BaseModel, Field
from typer.testing import CliRunner

from riskfield.cli import app
from riskfield.services.runtime import SERVICES, ServiceUnavailable, load_service
from riskfield.services.runtime.settings import NodeSettings
from riskfield.settings_help import setting_lines, summary, type_text


@cache
def loadable() -> dict[str, type[NodeSettings]]:
    out = {}
    for name in SERVICES:
        try:
            out[name] = load_service(name).settings
        except ServiceUnavailable:  # an extra not installed here
            continue
    return out


def settings_of(model: type[BaseModel], prefix: str = "") -> typing.Iterator[tuple[str, typing.Any]]:
    """Every key ``--set`` accepts: the fields, and a nested model's fields dotted."""
    for name, field in model.model_fields.items():
        yield prefix + name, field
        sub = field.annotation
        if isinstance(sub, type) and issubclass(sub, BaseModel):
            yield from settings_of(sub, f"{prefix}{name}.")


def test_every_setting_of_every_service_has_a_description():
    """The docstring under a field (``use_attribute_docstrings``) or ``Field(description=...)``."""
    services = loadable()
    assert {"router", "mapping", "safety-filter", "navigator"} <= set(services)
    missing = sorted({f"{name}: {key}" for name, model in services.items() for key, field in settings_of(model)
                      if not (field.description or "").strip()})
    assert not missing, f"{len(missing)} settings without a description:\n" + "\n".join(missing)


def test_types_read_as_written():
    pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
    assert type_text(tuple[pos, pos, pos]) == "tuple[float (> 0), float (> 0), float (> 0)]"
    assert type_text(Literal["2d", "3d"]) == "'2d' | '3d'"
    assert type_text(Path | None) == "Path | None"
    assert type_text(typing.Optional[str]) == "str | None"  # noqa: UP045 - the typing spelling on purpose
    assert type_text(tuple[str, ...]) == "tuple[str, ...]"
    assert type_text(dict[str, Annotated[float, Field(gt=0, le=1000)]]) == "dict[str, float (> 0, <= 1000)]"
    assert type_text(list[tuple[str, float, float]]) == "list[tuple[str, float, float]]"


def test_a_summary_is_the_first_sentence_of_the_first_paragraph():
    assert summary("Volume centre relative to the robot (e.g. raise it for a ground robot). More.") == (
        "Volume centre relative to the robot (e.g. raise it for a ground robot)")
    assert summary("Cut at 0.5 m. Then more.\n\nSecond paragraph.") == "Cut at 0.5 m"
    assert summary("one (a. b) two") == "one (a. b) two"
    assert summary("x" * 300, width=50).endswith("…") and len(summary("x" * 300, width=50)) == 50
    assert summary(None) == ""


def _help(service: str) -> str:
    r = CliRunner().invoke(app, ["run", service, "--help"])
    assert r.exit_code == 0, r.output
    return r.output


@pytest.mark.parametrize("service", ["mapping", "safety-filter", "navigator", "router"])
def test_run_help_prints_readable_types_defaults_and_descriptions(service):
    if service not in loadable():
        pytest.skip(f"{service} does not load here")
    out = _help(service)
    assert "FieldInfo" not in out and "Annotated[" not in out and "typing." not in out
    model = loadable()[service]
    lines = {line.split(":", 1)[0].strip(): line for line in out.splitlines() if line.startswith("  ")}
    for key, _field in settings_of(model):
        line = lines.get(key)
        assert line is not None, f"{key} is not in the help of {service}"
        assert " = " in line and "  — " in line, f"no default or description: {line!r}"
    if service == "mapping":
        assert "  half_extent: tuple[float (> 0), float (> 0), float (> 0)] = (3.0, 3.0, 1.25)  — Half size" in out
    assert "common to every node:" in out and "  connect_timeout_s: float (> 0) = 30.0  — " in out


def test_the_help_lines_match_the_model_one_to_one():
    lines = list(setting_lines(loadable()["navigator"], skip=NodeSettings.model_fields))
    assert [line.split(":", 1)[0].strip() for line in lines] == [
        key for key, _ in settings_of(loadable()["navigator"]) if key not in NodeSettings.model_fields]


@pytest.mark.parametrize(("typo", "meant"), [("mapng", "mapping"), ("safety_filter", "safety-filter"),
                                             ("navigater", "navigator")])
def test_an_unknown_service_gets_the_nearest_name(typo, meant):
    for args in (["run", typo], ["run", typo, "--help"], ["up", typo]):
        r = CliRunner().invoke(app, args)
        assert f"unknown service {typo!r}; did you mean {meant!r}?" in r.output, (args, r.output)
        assert r.exit_code == (0 if "--help" in args else 2), (args, r.output)
