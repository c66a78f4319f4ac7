#!/usr/bin/env python3
"""Write the lowest versions pyproject.toml allows, as a pip constraints file.

    python scripts/lowest_constraints.py            # writes .ci/lowest-constraints.txt
    python scripts/lowest_constraints.py --check    # exit 1 when the file is not what pyproject says

Every requirement of the project (its dependencies, every extra, the build backend's) must have
a lower bound (``>=`` or an exact ``==`` pin): that bound is what the code claims to run on, so
``.ci/lowest`` installs exactly it (``pip install -c .ci/lowest-constraints.txt``) and runs the
fast tests. A package named by several requirements gets the highest of their lower bounds (the
lowest version that satisfies all of them); environment markers are kept.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

from packaging.markers import Marker
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / ".ci" / "lowest-constraints.txt"
HEADER = ("# The lowest versions pyproject.toml allows (scripts/lowest_constraints.py writes this file;\n"
          "# tests/foundation/test_lowest_constraints.py checks it matches). `.ci/lowest` installs them.\n")


def requirements(pyproject: dict) -> list[Requirement]:
    """Every requirement of the project but its own extras (``riskfield[robot,...]``)."""
    project = pyproject["project"]
    texts = [*pyproject.get("build-system", {}).get("requires", []), *project.get("dependencies", [])]
    for extra in project.get("optional-dependencies", {}).values():
        texts += extra
    reqs = [Requirement(t) for t in texts]
    return [r for r in reqs if canonicalize_name(r.name) != canonicalize_name(project["name"])]


def lower_bound(req: Requirement) -> Version:
    """The version a requirement's ``>=`` / ``==`` / ``~=`` names as its lowest."""
    bounds = [Version(s.version) for s in req.specifier if s.operator in (">=", "==", "~=", "===")]
    if not bounds:
        raise ValueError(f"{req}: no lower bound (>= or ==): the lowest allowed version is undefined")
    low = max(bounds)
    if not req.specifier.contains(low, prereleases=True):
        raise ValueError(f"{req}: its lower bound {low} is excluded by its own specifier")
    return low


def lowest(pyproject: dict) -> dict[str, tuple[Version, Marker | None]]:
    """Canonical package name → (lowest allowed version, marker or None)."""
    out: dict[str, tuple[Version, Marker | None]] = {}
    for req in requirements(pyproject):
        name, low = canonicalize_name(req.name), lower_bound(req)
        if name in out:
            previous, marker = out[name]
            if str(marker) != str(req.marker):
                raise ValueError(f"{req.name}: required with different markers ({marker} and {req.marker})")
            low = max(low, previous)
        out[name] = (low, req.marker)
    return out


def render(pyproject: dict) -> str:
    lines = []
    for name, (version, marker) in sorted(lowest(pyproject).items()):
        lines.append(f"{name}=={version}" + (f"; {marker}" if marker is not None else ""))
    return HEADER + "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pyproject", type=Path, default=ROOT / "pyproject.toml")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--check", action="store_true", help="exit 1 when --out differs from pyproject.toml")
    args = parser.parse_args(argv)
    text = render(tomllib.loads(args.pyproject.read_text()))
    if args.check:
        if not args.out.is_file() or args.out.read_text() != text:
            print(f"{args.out} is not what {args.pyproject.name} allows: run scripts/lowest_constraints.py",
                  file=sys.stderr)
            return 1
        return 0
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
