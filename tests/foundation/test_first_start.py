"""A node's first start after set-up: no kernel compiled at start, and a cold start that says so.

``riskfield warmup`` (``make setup``; the session fixture in tests/conftest.py) fills numba's cache
with the nodes' kernels. Here each node with kernels starts in its own interpreter, as ``riskfield
demo`` and ``riskfield up`` start it, and must load every kernel from that cache: a kernel (or a new
signature of one) that a node's setup compiles but the warm-up does not cover fails this test.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import uuid
from pathlib import Path

import pytest

from riskfield.services.runtime import SERVICES
from riskfield.services.runtime.processes import ProcessRunner, client_session
from riskfield.services.runtime.warmup import (
    KERNEL_SERVICES,
    drop_cache,
    importers,
    stale_modules,
    to_drop,
    warm_up,
)
from riskfield.testing import StatusWatch

REPO = Path(__file__).resolve().parents[2]


def _starts() -> list[tuple[str, str, list[str]]]:
    """(label, service, --set arguments) of every start the warm-up covers."""
    out = []
    for service, variants in KERNEL_SERVICES.items():
        for i, overrides in enumerate(variants):
            args = [a for k, v in overrides.items() for a in ("--set", f"{k}={str(v).lower()}")]
            out.append((f"{service}-{i}", service, args))
    return out


def test_after_warmup_no_node_compiles_a_kernel_at_start(router_endpoint):
    """Every start of ``KERNEL_SERVICES`` (each settings variant) comes up, and runs the camera path
    up to the filter's first map, having compiled nothing: its status says ``kernels_compiled`` 0
    and its log has no "compiling kernel" line."""
    assert warm_up(say=lambda _line: None) == 0  # the session fixture warmed it: nothing left to do
    robot = f"first{uuid.uuid4().hex[:6]}"
    runner = ProcessRunner(router_endpoint)
    try:
        with client_session(router_endpoint) as s:
            watches = {}
            for label, service, args in _starts():
                # Each variant its own robot id, so that its status is its own.
                rid = f"{robot}{label.rsplit('-', 1)[1]}"
                runner.add(label, service, ["--robot", rid, "--set", "status_period_s=0.2", *args])
                watches[label] = StatusWatch(s, f"rf/{rid}/status/{service}")
            runner.start()
            for label, watch in watches.items():
                st = watch.wait(lambda st: "kernels_compiled" in st.extra, 120)
                assert st.extra["kernels_compiled"] == 0, runner.children[label].output
            # The first variants share a robot: camera → perception → mapping → filter runs, so the
            # kernels of a first frame and a first map are checked too, not only those of setup.
            watches["safety-filter-0"].wait(lambda st: st.received.get("map/esdf", 0) > 0, 120)
            watches["mapping-0"].wait(lambda st: st.published.get("map/esdf", 0) > 0, 60)
            for label, watch in watches.items():
                out = runner.children[label].output
                assert watch.latest is not None and watch.latest.extra["kernels_compiled"] == 0, out
                assert "compiling kernel" not in out, out
                watch.close()
    finally:
        runner.close()


def test_services_without_kernels_do_not_load_numba():
    """``KERNEL_SERVICES`` is complete: every other service starts without numba (a node that needs
    no compiled kernel must not pay numba's import either)."""
    others = [s for s in SERVICES if s not in KERNEL_SERVICES]
    code = textwrap.dedent(f"""
        import sys
        from riskfield.services.runtime import ServiceUnavailable, load_service
        for name in {others!r}:
            try:
                load_service(name)
            except ServiceUnavailable:
                continue
            assert "numba" not in sys.modules, name + " loads numba: add it to KERNEL_SERVICES (warmup.py)"
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]


def test_a_cold_start_says_which_kernel_it_compiles(tmp_path, router_endpoint):
    """With an empty cache (its own NUMBA_CACHE_DIR) a node compiles at start, and says so: each
    kernel by name with "n of N", then a warning naming the warm-up; its status counts them."""
    robot = f"cold{uuid.uuid4().hex[:6]}"
    runner = ProcessRunner(router_endpoint, env={"NUMBA_CACHE_DIR": str(tmp_path / "numba")})
    try:
        with client_session(router_endpoint) as s:
            watch = StatusWatch(s, f"rf/{robot}/status/simulator")
            runner.add("simulator", "simulator", ["--robot", robot, "--set", "status_period_s=0.2"])
            runner.start()
            st = watch.wait(lambda st: "kernels_compiled" in st.extra, 180)
            out = runner.children["simulator"].output
            assert st.extra["kernels_compiled"] >= 2, out
            assert "compiling kernel simulator.kernels.pack_rays_kernel (1 of 2" in out, out
            assert "compiling kernel simulator.kernels.shade_kernel (2 of 2" in out, out
            assert "`riskfield warmup`" in out, out
            watch.close()
    finally:
        runner.close()
    assert any((tmp_path / "numba").rglob("*.nbi"))  # it went to the cache the node was given, not the tree


def test_stale_modules_follow_importers(tmp_path):
    """A changed module makes every module that imports it (directly or through others) stale:
    numba would keep their cached kernels, which hold the changed module's code and constants."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    files = {}
    for name, text in {"a": "X = 1\n", "b": "from .a import X\n", "c": "from pkg import b\n",
                       "d": "import math\n"}.items():
        (pkg / f"{name}.py").write_text(text)
        files[f"pkg.{name}"] = pkg / f"{name}.py"
    graph = importers(files)
    assert graph["pkg.a"] == {"pkg.b"} and graph["pkg.b"] == {"pkg.c"} and graph["pkg.d"] == set()
    old = {n: "h" for n in files}
    assert stale_modules(old, {**old, "pkg.a": "h2"}, files) == {"pkg.a", "pkg.b", "pkg.c"}
    assert stale_modules(old, {**old, "pkg.d": "h2"}, files) == {"pkg.d"}
    assert stale_modules(old, old, files) == set()


def test_a_cache_without_a_stamp_is_dropped_whole(tmp_path):
    """A cache nobody stamped (a copied tree: its kernels inlined an older model.py) goes entirely;
    a stamp that differs only in sources drops the changed modules and their importers."""
    files = {m: tmp_path / f"{m.split('.')[-1]}.py" for m in ("pkg.a", "pkg.b")}
    files["pkg.a"].write_text("X = 1\n")
    files["pkg.b"].write_text("from pkg.a import X\n")
    now = {"sources": {"pkg.a": "h2", "pkg.b": "h"}, "numba": "1"}
    assert to_drop({}, now, files) == {"pkg.a", "pkg.b"}
    assert to_drop({**now, "numba": "0"}, now, files) == {"pkg.a", "pkg.b"}
    assert to_drop({**now, "sources": {"pkg.a": "h2", "pkg.b": "h0"}}, now, files) == {"pkg.b"}


def test_drop_cache_removes_only_the_modules_entries(tmp_path, monkeypatch):
    """Only ``<stem>.*.nbi/.nbc`` of the stale modules go (not another module's, not bytecode)."""
    import riskfield.services.runtime.warmup as w

    cache = tmp_path / "cache"
    cache.mkdir()
    names = ["a.f-1.py311.nbi", "a.f-1.py311.1.nbc", "ab.g-2.py311.nbi", "a.cpython-311.pyc"]
    for n in names:
        (cache / n).write_text("x")
    monkeypatch.setattr(w, "cache_dir", lambda _source: cache)
    assert drop_cache(["m"], {"m": tmp_path / "a.py"}) == 2
    assert sorted(p.name for p in cache.iterdir()) == ["a.cpython-311.pyc", "ab.g-2.py311.nbi"]


def test_warmup_stamp_records_what_it_compiled_for():
    """The stamp next to the cache names numba, Python, the CPU, every source's hash and the
    services warmed: what makes a second ``make setup`` a no-op, and a changed source a re-warm."""
    from riskfield.services.runtime.warmup import STAMP, cache_dir

    folder = cache_dir(REPO / "services" / "runtime" / "warmup.py")
    assert folder is not None
    stamp = json.loads((folder / STAMP).read_text())
    assert {"numba", "llvmlite", "python", "cpu", "cpu_features", "sources", "services"} <= set(stamp)
    assert set(KERNEL_SERVICES) <= set(stamp["services"])
    assert "riskfield.services.mapping.esdf_kernels" in stamp["sources"]


@pytest.mark.parametrize("argv", [["warmup", "no-such-service"]])
def test_warmup_command_refuses_an_unknown_service(argv):
    r = subprocess.run([sys.executable, "-m", "riskfield", *argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "unknown service" in r.stderr, r.stderr


def test_importers_of_a_package_submodule_are_the_submodules_only(tmp_path):
    """``from pkg import mod`` depends on mod, not on everything pkg/__init__ imports."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    files = {}
    for name, text in {"__init__": "from .big import Y\n", "big": "Y = 2\n", "mod": "X = 1\n",
                       "user": "from . import mod\n", "other": "from pkg import Y\n"}.items():
        (pkg / f"{name}.py").write_text(text)
        files["pkg" if name == "__init__" else f"pkg.{name}"] = pkg / f"{name}.py"
    graph = importers(files)
    assert graph["pkg.mod"] == {"pkg.user"} and graph["pkg"] == {"pkg.other"}
    assert stale_modules({n: "h" for n in files}, {**{n: "h" for n in files}, "pkg.big": "h2"}, files) == {
        "pkg.big", "pkg", "pkg.other"}


def test_compile_watch_counts_riskfield_kernels_not_numbas_helpers(caplog):
    """numba's own helpers compiled inside one of ours are neither counted nor logged; the outermost
    kernel of ours is what a start-up report names; an event it cannot read breaks nothing."""
    import logging
    import types

    from riskfield.services.runtime.jit import CompileWatch

    def fake(module: str, name: str) -> types.SimpleNamespace:
        fn = types.SimpleNamespace(__module__=module, __qualname__=name)
        return types.SimpleNamespace(py_func=fn, overloads={})

    watch = CompileWatch(logging.getLogger("test-kernels"))
    with caplog.at_level(logging.INFO, logger="test-kernels"):
        watch._start(fake("riskfield.services.mapping.esdf_kernels", "scan"))
        watch._start(fake("numba.cpython.builtins", "ol_max.<locals>.impl"))
        assert watch.current() is not None and watch.current()[0] == "mapping.esdf_kernels.scan"
        watch._end()
        watch._start(fake("riskfield.services.mapping.raycast", "ray_voxels"))
        watch._end()
        watch._end()
        watch._end()  # unbalanced: ignored
        watch._start(None)  # not a dispatcher: named "?", not ours
        watch._end()
    assert watch.compiled == 2 and watch.current() is None and watch.seconds >= 0
    lines = [r.getMessage() for r in caplog.records if "compiling kernel" in r.getMessage()]
    assert len(lines) == 2 and "mapping.esdf_kernels.scan (1 of " in lines[0], lines
    assert "mapping.raycast.ray_voxels (2 of " in lines[1], lines
