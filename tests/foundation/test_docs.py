"""The docs say nothing the code contradicts, where a test can tell: relative links and the
project's file paths resolve, the settings they name exist, the config files they show are
accepted, and every ``riskfield`` command in a ```bash block parses (without running anything)."""

from __future__ import annotations

import re
import shlex
from functools import cache
from pathlib import Path

import pytest
import typer
import yaml

from riskfield.cli import app
from riskfield.services.runtime import SERVICES, ServiceUnavailable, load_service
from riskfield.services.runtime.settings import check_keys, setting_names

try:  # newer typer parses with its own copy of Click
    from typer._click import exceptions as click_errors
except ImportError:  # pragma: no cover - typer on the installed Click
    from click import exceptions as click_errors
#: How parsing ends early (``--version``, ``--help``): typer's Exit, and Click's where it has one.
EXITS = (typer.Exit, *((click_errors.Exit,) if hasattr(click_errors, "Exit") else ()))

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "examples" / "README.md",
        ROOT / "services" / "perception" / "README.md"]
#: Top-level folders of the repository, and the import namespace's spelling of three of them.
FOLDERS = {p.name for p in ROOT.iterdir() if p.is_dir() and not p.name.startswith(".")} - {"out"}
NAMESPACE = {"riskfield/protocol/": "protocol/", "riskfield/services/": "services/", "riskfield/edge/": "edge/"}
#: Files the project writes when it runs (not in a checkout).
GENERATED = ("out/", "deploy/secrets/", "deploy/wheels/", "checkpoints/", "benchmarks/out")


def _id(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, re.S)


@cache
def settings() -> dict[str, type]:
    out = {}
    for name in SERVICES:
        try:
            out[name] = load_service(name).settings
        except ServiceUnavailable:  # an extra not installed here
            continue
    return out


@cache
def all_keys() -> set[str]:
    return {k for model in settings().values() for k in setting_names(model)}


@pytest.mark.parametrize("doc", DOCS, ids=_id)
def test_relative_links_resolve(doc):
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
        if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # a URL or an anchor of this page
        if not (doc.parent / target.split("#")[0]).exists():
            broken.append(target)
    assert not broken, f"{_id(doc)} links to {broken}, which do not exist"


@pytest.mark.parametrize("doc", DOCS, ids=_id)
def test_the_project_files_a_doc_names_exist(doc):
    """A backticked path that starts in one of the repository's folders (or any ``.md``) exists."""
    missing = []
    for path in set(re.findall(r"`([A-Za-z0-9_.\-]+/[A-Za-z0-9_./\-]+)`", doc.read_text())):
        for namespace, folder in NAMESPACE.items():
            if path.startswith(namespace):
                path = folder + path[len(namespace):]
        first = path.split("/")[0]
        if path.startswith(GENERATED) or re.search(r"\b(NAME|SERVICE|KEY|N)\b|[*<{]", path):
            continue  # written at run time, or a placeholder (benches/NAME.py, deploy/env/*.env)
        if "." not in path.rsplit("/", 1)[-1] and not path.endswith("/"):
            continue  # no file name: a key or a ROS topic (riskfield/costmap), not a path
        if first in FOLDERS or path.endswith(".md"):
            if not ((ROOT / path).exists() or (doc.parent / path).exists()):
                missing.append(path)
    assert not missing, f"{_id(doc)} names {sorted(missing)}, which are not in the project"


@pytest.mark.parametrize("doc", DOCS, ids=_id)
def test_the_settings_a_doc_sets_exist(doc):
    text = doc.read_text()
    unknown = []
    for key in re.findall(r"--set[ =]([A-Za-z_][A-Za-z0-9_.]*)=", text):
        if key == "key" or f"unknown setting '{key}'" in text:
            continue  # the placeholder, or the typo the doc shows the error of
        if key.split(".")[0] not in all_keys():
            unknown.append(key)
    assert not unknown, f"{_id(doc)} sets {unknown}, which no service has"


@pytest.mark.parametrize("doc", DOCS, ids=_id)
def test_the_config_files_a_doc_shows_are_accepted(doc):
    """A ```yaml block with a service's section is a riskfield config file: every key is checked
    as the node checks it (the section's keys against that service, the top level against all)."""
    for block in _blocks(doc.read_text(), "ya?ml"):
        data = yaml.safe_load(block)
        if not isinstance(data, dict) or not set(data) & set(SERVICES):
            continue  # another program's file (Nav2 parameters, a compose file)
        for key, value in data.items():
            if key in SERVICES:
                if key in settings():
                    check_keys(settings()[key], value or {}, key, f"section {key!r} in {_id(doc)}")
            else:
                assert key in all_keys(), f"{_id(doc)}: top-level {key!r} is no service's setting"


def _commands(doc: Path) -> list[list[str]]:
    out = []
    for block in _blocks(doc.read_text(), "bash"):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            while words and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*=.*", words[0]):
                words.pop(0)  # VAR=value before the command
            if words and words[-1] == "&":
                words.pop()
            if words and words[0] in ("riskfield", ".venv/bin/riskfield"):
                out.append(words[1:])
    return out


def _parse(args: list[str]) -> None:
    """What click does with a command line before it calls anything: the group's options, the
    subcommand, its options and arguments. ``--version`` and ``--help`` end parsing cleanly."""
    group = typer.main.get_command(app)
    try:
        with group.make_context("riskfield", list(args)) as ctx:
            protected = getattr(ctx, "protected_args", None)
            rest = [*(ctx._protected_args if protected is None else protected), *ctx.args]
            if not rest:
                return
            name, command, sub = group.resolve_command(ctx, rest)
            assert command is not None, f"no command {name!r}"
            with command.make_context(name, sub, parent=ctx) as sub_ctx:
                if name == "run" and sub_ctx.params.get("service"):
                    assert sub_ctx.params["service"] in SERVICES, f"unknown service {sub_ctx.params['service']!r}"
                if name == "up":
                    stray = set(sub_ctx.params.get("services") or []) - set(SERVICES)
                    assert not stray, f"unknown services {sorted(stray)}"
    except EXITS:
        return


@pytest.mark.parametrize("doc", [d for d in DOCS if _commands(d)], ids=_id)
def test_the_riskfield_commands_in_a_doc_parse(doc):
    bad = []
    for args in _commands(doc):
        try:
            _parse(args)
        except (click_errors.UsageError, AssertionError) as exc:
            bad.append(f"riskfield {shlex.join(args)}: {exc}")
    assert not bad, "\n".join(bad)


def test_the_parser_refuses_what_the_cli_refuses():
    """The check above can fail: a misspelt option, an unknown command or service."""
    for args in (["run", "mapping", "--sett", "x=1"], ["serve"], ["run", "maping"], ["up", "navigatr"]):
        with pytest.raises((click_errors.UsageError, AssertionError)):
            _parse(args)
    _parse(["run", "mapping", "--set", "voxel_size=0.1"])
    _parse(["--version"])


def test_no_doc_installs_riskfield_from_the_package_index():
    """It is not published there: a doc installs the checkout or a wheel built from it."""
    by_name = re.compile(r"pip install[^`\n]*?[\s'\"]riskfield(\[[^\]]*\])?['\"]?(\s|$|`)")
    found = [f"{_id(d)}: {m.group(0).strip()}" for d in DOCS for m in by_name.finditer(d.read_text())]
    assert not found, found
    readme = (ROOT / "README.md").read_text()
    assert "pip wheel" in readme and "not published" in readme


def test_the_docs_name_the_filters_real_interpolation():
    """Where a doc says how the safety filter reads the grid, it is the filter's default."""
    from riskfield.services.safety_filter.config import QpParams

    default = QpParams.model_fields["interpolation"].default
    claims = []
    for doc in DOCS:
        text = " ".join(doc.read_text().split())
        claims += [(doc, m) for m in re.findall(r"safety filter reads the grid[^.]*?`interpolation = \"(\w+)\"`", text)]
        claims += [(doc, m) for m in re.findall(r"[Tt]he filter reads the ESDF with a (\w+ cubic B-spline)", text)]
        assert not re.search(r"trilinear[^.()]*\(this is what the safety filter does\)", text), _id(doc)
    assert claims, "no doc says how the filter reads the ESDF"
    for doc, said in claims:
        assert said in (default, "smoothing cubic B-spline") and default == "bspline_smooth", (_id(doc), said)
