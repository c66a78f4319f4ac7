"""Print the dependencies of ``riskfield[EXTRAS]`` from pyproject.toml, one per line, for
``pip install -r``: the images install them in a layer of their own, before the source is copied,
so that an edit of the source rebuilds only the project's own install and the kernels' warm-up.

    python deploy/requirements.py robot,mapping,sim > requirements.txt
    python deploy/requirements.py robot-site > requirements.txt     # a site's extras (SITES)
    python deploy/requirements.py --extras robot-site               # robot,camera (for pip's [...])
"""

from __future__ import annotations

import re
import sys
import tomllib

#: The extras of the nodes a site runs. The robot computer runs the filter, the hardware bridges and the
#: camera (docker-compose.yml's robot profile, ``riskfield up --profile robot``, deploy/robot/install.sh):
#: no torch, no open3d.
SITES: dict[str, tuple[str, ...]] = {"robot-site": ("robot", "camera")}


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
    args = sys.argv[1:]
    if args[:1] == ["--extras"]:  # no pyproject needed: deploy/robot/install.sh runs it from anywhere
        if len(args) < 2 or args[1] not in SITES:
            sys.exit(f"requirements: --extras SITE, one of {', '.join(SITES)}")
        print(",".join(SITES[args[1]]))
        sys.exit(0)
    with open("pyproject.toml", "rb") as f:
        proj = tomllib.load(f)["project"]
    wanted = [x for e in (args[0] if args else "").split(",") if e for x in SITES.get(e, (e,))]
    print("\n".join(requirements(wanted, proj)))
