"""Compile every kernel a node loads at start, once, ahead of start: ``riskfield warmup``.

A node loads its numba kernels in its service's setup (the mapper's, the filter's step, the
simulated camera's and perception's, each ``warm_up``): from numba's on-disk cache in
milliseconds, or compiled for tens of seconds when the cache is cold (a fresh checkout, a new
image). :func:`warm_up` runs those same setups, one service after another in this process on an
embedded router, so the cache holds exactly the signatures the nodes load, in the place they load
them from (``jit``'s docstring: numba picks it from ``NUMBA_CACHE_DIR`` and the source path, both the
same for the nodes that run later with this environment and install).

Cheap when done: a stamp next to the cache records what the cache was filled for (every source
file's hash, numba's and Python's versions, the CPU); the same stamp means nothing to do. A changed
stamp also drops the cache entries numba itself would keep although stale: numba checks only the
source file of the kernel itself, while a kernel's machine code also holds the kernels it calls and
the module constants it reads, from other files ("Cache invalidation fails to recognize changes in
symbols defined in a different file", numba's docs, developer/caching.rst, "Caching limitations").
So the entries of every file that changed, or imports (directly or not) one that changed, go.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.metadata
import importlib.util
import json
import logging
import os
import platform
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

#: Services whose start loads numba kernels, with the settings whose kernels differ (each a start):
#: the demo's and the docker compositions' nodes. ``tests/foundation/test_first_start.py`` checks that
#: every other service starts without numba, and these without compiling after a warm-up.
KERNEL_SERVICES: dict[str, tuple[dict[str, Any], ...]] = {
    "simulator": ({},),
    "perception": ({}, {"geometry": "rgbd"}),
    "mapping": ({"output": "2d"}, {"output": "3d"}),
    "safety-filter": ({},),
}
#: Packages whose source the stamp covers (kernels and everything they read: configs, decoded arrays).
PACKAGES = ("riskfield.services", "riskfield.protocol", "riskfield.edge")
STAMP = "riskfield-warmup.json"


def _probe() -> None:
    """Any function of this file: where numba would cache a kernel of ``services/runtime``."""


def cache_dir(source: str | os.PathLike) -> Path | None:
    """The folder numba caches the kernels of ``source`` in, chosen as numba chooses it for this
    process (numba/core/caching.py, ``CacheImpl.__init__``: the first of ``_locator_classes`` whose
    ``from_function`` accepts the file); None without numba or without a writable place."""
    try:
        from numba.core.caching import CacheImpl
    except ImportError:
        return None
    for cls in CacheImpl._locator_classes:
        locator = cls.from_function(_probe, str(source))
        if locator is not None:
            return Path(locator.get_cache_path())
    return None


def sources() -> dict[str, Path]:
    """Module name → source file of every module of ``PACKAGES``."""
    out: dict[str, Path] = {}
    for package in PACKAGES:
        try:
            spec = importlib.util.find_spec(package)
        except ModuleNotFoundError:
            continue
        for root in (spec.submodule_search_locations or ()) if spec else ():
            for path in sorted(Path(root).rglob("*.py")):
                parts = path.relative_to(root).with_suffix("").parts
                if parts[-1] == "__init__":
                    parts = parts[:-1]
                if "__pycache__" not in parts:
                    out[".".join((package, *parts))] = path
    return out


def fingerprint(files: dict[str, Path]) -> dict[str, Any]:
    """What the cache was filled for: numba's cache key besides the argument types (numba and
    llvmlite versions, Python, the CPU name and features: ``CPUCodegen.magic_tuple``) and every
    source file's hash."""
    import llvmlite.binding as llvm
    from numba.core import config

    def version(dist: str) -> str:
        try:
            return importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            return ""

    cpu = config.CPU_NAME or llvm.get_host_cpu_name()
    features = config.CPU_FEATURES if config.CPU_FEATURES is not None else llvm.get_host_cpu_features().flatten()
    return {
        "numba": version("numba"), "llvmlite": version("llvmlite"), "python": platform.python_version(),
        "cpu": cpu, "cpu_features": hashlib.sha256(features.encode()).hexdigest()[:16],
        "sources": {name: hashlib.sha256(path.read_bytes()).hexdigest() for name, path in files.items()},
    }


def importers(files: dict[str, Path]) -> dict[str, set[str]]:
    """Module → the modules of ``files`` that import it (read from their source, not imported)."""
    names = set(files)
    out: dict[str, set[str]] = {name: set() for name in names}
    for name, path in files.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        try:
            tree = ast.parse(path.read_bytes())
        except SyntaxError:
            continue
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")
                    anchor = anchor[:len(anchor) - node.level + 1]
                    base = ".".join([*anchor, *([base] if base else [])])
                # ``from pkg import mod`` reads mod, not the rest of pkg/__init__; ``from m import X``, m.
                subs = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in names]
                targets = subs + ([base] if len(subs) < len(node.names) else [])
            for target in targets:
                if target in names and target != name:
                    out[target].add(name)
    return out


def stale_modules(old: dict[str, str], new: dict[str, str], files: dict[str, Path]) -> set[str]:
    """Modules whose cached kernels may hold old code: changed ones and all that import them."""
    changed = {name for name in new if old.get(name) != new[name]} | (set(old) - set(new))
    graph = importers(files)
    out, todo = set(), list(changed)
    while todo:
        name = todo.pop()
        if name in out:
            continue
        out.add(name)
        todo.extend(graph.get(name, ()))
    return out & set(files)


def to_drop(old: dict[str, Any], now: dict[str, Any], files: dict[str, Path]) -> set[str]:
    """The modules whose cache entries go, from the old stamp (``{}``: none) and the new one."""
    if not old or any(old.get(k) != now[k] for k in now if k != "sources"):
        # No stamp: what is cached was built from sources nobody recorded (a copied tree, a cache
        # from before warmup), and numba would keep entries whose inlined callees changed. Another
        # numba, Python or CPU: numba keys its entries by those anyway.
        return set(files)
    return stale_modules(old.get("sources", {}), now["sources"], files)


def drop_cache(modules: Iterable[str], files: dict[str, Path]) -> int:
    """Delete numba's cache entries (``<file stem>.<kernel>-<line>.pyXY.nbi/.nbc``,
    ``CacheImpl.get_filename_base``) of ``modules``; how many files went."""
    n = 0
    for name in modules:
        path = files[name]
        folder = cache_dir(path)
        if folder is None or not folder.is_dir():
            continue
        for entry in folder.glob(f"{path.stem}.*"):
            if entry.suffix in (".nbi", ".nbc"):
                entry.unlink(missing_ok=True)
                n += 1
    return n


def _warm_one(service: str, overrides: dict[str, Any], endpoint: str) -> None:
    """The start of one node, setup included, on ``endpoint``; then its close."""
    from .node import Node
    from .service import build_settings, load_service

    spec = load_service(service)
    settings = build_settings(spec, {"connect": [endpoint], "robot": "warmup", "log_level": "WARNING",
                                     **overrides})
    node = Node(spec.name, settings)
    handle = None
    try:
        handle = spec.setup(node, settings)
    finally:
        close = getattr(handle, "close", None)
        if callable(close):
            close()
        node.close()


def warm_up(services: Sequence[str] | None = None, *, force: bool = False,
            say: Callable[[str], None] = print) -> int:
    """Fill numba's cache with every kernel the nodes of ``services`` (default: ``KERNEL_SERVICES``)
    load at start; kernels compiled (0 when the cache was warm). Raises ``ServiceUnavailable`` for
    an unknown service; a service whose extra is not installed is skipped with a line."""
    from .jit import HAVE_NUMBA, watch_compiles
    from .processes import EmbeddedRouter
    from .service import SERVICES, ServiceUnavailable, load_service

    if not HAVE_NUMBA:
        say("warmup: numba is not installed: nothing to compile")
        return 0
    wanted = list(services) if services else list(KERNEL_SERVICES)
    unknown = [s for s in wanted if s not in SERVICES]
    if unknown:
        raise ServiceUnavailable(f"unknown service(s): {', '.join(unknown)}; known: {', '.join(SERVICES)}")
    files = sources()
    stamp_dir = cache_dir(__file__)
    stamp = stamp_dir / STAMP if stamp_dir is not None else None
    now = fingerprint(files)
    old: dict[str, Any] = {}
    if stamp is not None and stamp.is_file():
        try:
            old = json.loads(stamp.read_text())
        except (OSError, ValueError):
            old = {}
    done = set(old.get("services", [])) if {k: old.get(k) for k in now} == now else set()
    todo = [s for s in wanted if force or s not in done]
    where = stamp_dir if stamp_dir is not None else "nowhere (no writable cache folder: every start compiles)"
    if not todo:
        say(f"warmup: kernels of {', '.join(wanted)} are compiled (numba cache: {where})")
        return 0
    if not old or any(old.get(k) != now[k] for k in now):
        stale = to_drop(old, now, files)
        dropped = drop_cache(stale, files)
        if dropped:
            say(f"warmup: dropped {dropped} cache file(s) of {len(stale)} changed module(s) and their importers")
        done = set()
        todo = list(dict.fromkeys([*wanted, *(s for s in old.get("services", []) if s in SERVICES)]))
    watch = watch_compiles()
    if watch is None:  # pragma: no cover - HAVE_NUMBA means numba is loaded
        raise RuntimeError("numba is installed but not loaded")
    logging.getLogger(watch.log.name).setLevel(logging.INFO)  # compile progress, above the nodes' WARNING
    t_all = time.monotonic()
    before_all = watch.compiled
    warmed = set(done)
    with EmbeddedRouter() as router:
        for service in todo:
            try:
                load_service(service)
            except ServiceUnavailable as exc:
                say(f"warmup: skipped {service}: {exc}")
                continue
            for overrides in KERNEL_SERVICES.get(service, ({},)):
                label = service + "".join(f" {k}={v}" for k, v in overrides.items())
                t0, before = time.monotonic(), watch.compiled
                say(f"warmup: {label} ...")
                _warm_one(service, overrides, router.endpoint)
                say(f"warmup: {label}: {watch.compiled - before} kernel signature(s) compiled in "
                    f"{time.monotonic() - t0:.1f} s")
            warmed.add(service)
    if stamp is not None:
        stamp.write_text(json.dumps({**now, "services": sorted(warmed)}, indent=1) + "\n")
    total = watch.compiled - before_all
    say(f"warmup: done in {time.monotonic() - t_all:.1f} s, {total} kernel signature(s) compiled "
        f"(numba cache: {where})")
    return total


if __name__ == "__main__":  # pragma: no cover - ``riskfield warmup`` is the command
    warm_up(sys.argv[1:])
