"""Print the dependencies of ``riskfield[EXTRAS]`` from pyproject.toml, one per line, for
``pip install -r``: the images install them in a layer of their own, before the source is copied,
so that an edit of the source rebuilds only the project's own install and the kernels' warm-up.

    python deploy/requirements.py robot,mapping,sim > requirements.txt
"""

from __future__ import annotations

import re
import sys
import tomllib


def requirements(extras: list[str], project: dict) -> list[str]:
    """The base dependencies plus each extra's, with ``riskfield[...]`` self-references expanded."""
    name = project["name"]
    optional = project.get("optional-dependencies", {})
    out: list[str] = list(project.get("dependencies", []))
    seen: set[str] = set()
    todo = list(extras)
    while todo:
        extra = todo.pop()
        if extra in seen:
            continue
        if extra not in optional:
            raise SystemExit(f"requirements: no extra {extra!r} in pyproject.toml (have: {', '.join(optional)})")
        seen.add(extra)
        for req in optional[extra]:
            self_ref = re.fullmatch(rf"{re.escape(name)}\[([^\]]+)\]", req.strip())
            if self_ref:
                todo.extend(e.strip() for e in self_ref.group(1).split(","))
            elif req not in out:
                out.append(req)
    return out


if __name__ == "__main__":
    with open("pyproject.toml", "rb") as f:
        proj = tomllib.load(f)["project"]
    wanted = [e for e in (sys.argv[1] if len(sys.argv) > 1 else "").split(",") if e]
    print("\n".join(requirements(wanted, proj)))
