"""The layering of docs/architecture.md, enforced: the import-linter contracts of pyproject.toml.

protocol < services.runtime < services.fields / services.geometry < services and edge <
riskfield.experiments / riskfield.cli; no service imports another; no shipped module imports
``riskfield.testing``. Imports inside functions count too (grimp reads every ``import``).

The repository's folders (``protocol/``, ``services/``, ``edge/``) are mapped onto the one
``riskfield`` package by setup.py, which grimp cannot follow; so the test copies the sources into
the layout Python sees (``riskfield/services/...``) and lints that copy.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
import tomllib
from collections.abc import Mapping, Set
from pathlib import Path

import pytest

# One xdist worker runs the whole module (``make check``: ``--dist loadgroup``):
# the copied package tree and grimp's cache of it are built once per worker.
pytestmark = pytest.mark.xdist_group("test_layers")

ROOT = Path(__file__).resolve().parents[2]
PYPROJECT = ROOT / "pyproject.toml"
#: repository folder → where it sits in the ``riskfield`` package (as setup.py maps it)
FOLDERS = {"riskfield": "riskfield", "protocol": "riskfield/protocol", "services": "riskfield/services",
           "edge": "riskfield/edge"}


def _contracts() -> list[str]:
    config = tomllib.loads(PYPROJECT.read_text())["tool"]["importlinter"]
    return [c["id"] for c in config["contracts"]]


@pytest.fixture(scope="module")
def package_tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    top = tmp_path_factory.mktemp("layers")

    def only_sources(folder: str, names: list[str]) -> list[str]:
        return [n for n in names if n == "__pycache__" or not (n.endswith(".py") or (Path(folder) / n).is_dir())]

    for folder, target in FOLDERS.items():
        shutil.copytree(ROOT / folder, top / target, ignore=only_sources, dirs_exist_ok=True)
    return top


def _lint(tree: Path, contract: str) -> subprocess.CompletedProcess:
    script = Path(sys.executable).with_name("lint-imports")
    cmd = [str(script)] if script.exists() else [shutil.which("lint-imports") or "lint-imports"]
    env = {**os.environ, "PYTHONPATH": str(tree), "COLUMNS": "200"}
    # grimp's cache (keyed by each file's modification time) lives in the copy, so it is rebuilt for
    # every test session and shared by the contracts of one.
    return subprocess.run([*cmd, "--cache-dir", str(tree / ".import_linter_cache"), "--contract", contract,
                           str(PYPROJECT)], cwd=tree, env=env, capture_output=True, text=True, timeout=120)


def test_the_copy_is_what_python_imports(package_tree: Path):
    """The linted tree resolves ``riskfield.services`` to the copy, not to the editable install."""
    r = subprocess.run([sys.executable, "-c", "import riskfield.services.runtime as m; print(m.__file__)"],
                       cwd=package_tree, env={**os.environ, "PYTHONPATH": str(package_tree)},
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert Path(r.stdout.strip()).is_relative_to(package_tree)


@pytest.mark.parametrize("contract", _contracts())
def test_import_contract_is_kept(package_tree: Path, contract: str):
    r = _lint(package_tree, contract)
    assert r.returncode == 0, r.stdout[-6000:] + r.stderr[-2000:]
    assert "0 broken" in r.stdout


def test_a_broken_contract_is_reported(package_tree: Path, tmp_path: Path):
    """The check can fail: a service importing another breaks the independence contract."""
    bad = tmp_path / "tree"
    shutil.copytree(package_tree, bad, ignore=shutil.ignore_patterns(".import_linter_cache"))
    victim = bad / "riskfield" / "services" / "relay" / "node.py"
    victim.write_text(victim.read_text() + "\nfrom riskfield.services.navigator import waypoints  # noqa\n")
    r = _lint(bad, "services-independent")
    assert r.returncode != 0
    assert "riskfield.services.relay" in r.stdout and "riskfield.services.navigator" in r.stdout


# -- no import cycles ---------------------------------------------------------------------------


def import_loops(edges: Mapping[str, Set[str]]) -> list[frozenset[str]]:
    """The strongly connected components of more than one module: every set of modules that
    import each other directly or around a loop (Tarjan, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    loops: list[frozenset[str]] = []
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = set()
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.add(w)
                    if w == v:
                        break
                if len(component) > 1:
                    loops.append(frozenset(component))
    return loops


def test_import_loops_finds_direct_and_longer_loops_only():
    edges = {"a": {"b"}, "b": {"a"}, "c": {"d"}, "d": {"e"}, "e": {"c", "f"}, "f": set(), "g": {"g"}}
    assert sorted(map(sorted, import_loops(edges))) == [["a", "b"], ["c", "d", "e"]]


def test_no_two_modules_import_each_other_directly_or_around_a_loop(package_tree: Path):
    """Every ``import`` grimp reads counts: inside functions and under ``TYPE_CHECKING`` too (a
    loop that only type hints close is still two modules that must change together)."""
    script = textwrap.dedent("""
        import json, sys
        import grimp
        g = grimp.build_graph("riskfield", cache_dir=sys.argv[1])
        print(json.dumps({m: sorted(g.find_modules_directly_imported_by(m)) for m in g.modules}))
    """)
    r = subprocess.run([sys.executable, "-c", script, str(package_tree / ".import_linter_cache")], cwd=package_tree,
                       env={**os.environ, "PYTHONPATH": str(package_tree)}, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    edges = {m: set(imported) for m, imported in json.loads(r.stdout).items()}
    assert len(edges) == len(list(package_tree.rglob("*.py")))  # the whole package was read
    loops = import_loops(edges)
    assert [sorted(loop) for loop in loops] == []  # no allow-list: none is known, none may come


def test_the_runtime_settings_import_no_service():
    """The runtime knows no service: reading settings imports only the runtime and the protocol
    (the other services' keys come from the layer above, ``riskfield.cli``)."""
    r = subprocess.run([sys.executable, "-c", "import json, sys, riskfield.services.runtime.settings; "
                        "print(json.dumps(sorted(sys.modules)))"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    ours = [m for m in json.loads(r.stdout) if m.startswith("riskfield.")]
    assert "riskfield.services.runtime.settings" in ours
    allowed = ("riskfield.services.runtime", "riskfield.protocol")
    assert [m for m in ours if m not in ("riskfield.services",) and not m.startswith(allowed)] == []
