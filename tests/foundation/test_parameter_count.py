"""Functions in shipped code take fewer than ten parameters (parameter objects instead, and compiled
kernels their arrays through a workspace). ``LEFT`` is what still takes more, with today's count: a
function not in it that reaches ten fails, a listed one that grows fails, and one brought under ten
must leave the list, so the list only shrinks."""

from __future__ import annotations

import ast
from pathlib import Path

from .test_platforms import REPO, shipped_trees

LIMIT = 10

#: (file, qualified name) → parameters (``self``/``cls`` not counted), of the functions still at the limit.
LEFT: dict[tuple[str, str], int] = {
    ("riskfield/cli.py", "up"): 15,
    ("riskfield/cli.py", "run"): 12,
    ("riskfield/cli.py", "record"): 11,
    ("riskfield/cli.py", "view"): 10,
    ("riskfield/experiments/authors_bench.py", "run"): 13,
    ("riskfield/experiments/benches/crowd.py", "crowd"): 12,
    ("riskfield/experiments/benches/latency.py", "latency"): 13,
    ("riskfield/experiments/benches/mapping.py", "main"): 10,
    ("riskfield/experiments/benches/safety.py", "safety"): 13,
    ("riskfield/experiments/benches/safety_authors.py", "authors_run"): 11,
    ("services/perception/kernels.py", "match_kernel"): 18,
    ("services/perception/kernels.py", "fuse_kernel"): 17,
    ("services/perception/kernels.py", "depth_noise_kernel"): 11,
    ("services/perception/kernels.py", "current_frame_kernel"): 10,
    ("services/perception/mast3r_backend.py", "keyframe_message"): 12,
    ("services/safety_filter/barriers.py", "DoubleIntegrator.__init__"): 10,
    ("services/safety_filter/compiled.py", "CompiledStep.__init__"): 12,
    ("services/safety_filter/model.py", "flow"): 15,
    ("services/safety_filter/model.py", "point_row"): 13,
    ("services/safety_filter/model.py", "point_rows"): 13,
    ("services/safety_filter/model.py", "barriers"): 11,
    ("services/safety_filter/model.py", "object_course"): 10,
    ("services/safety_filter/model.py", "object_sample"): 10,
    ("services/simulator/kernels.py", "shade_kernel"): 21,
}


def parameters(fn: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> int:
    a = fn.args
    n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
    first = (a.posonlyargs + a.args)[:1]
    return n - (method and bool(first) and first[0].arg in ("self", "cls"))


def counts(path: Path, tree: ast.Module) -> dict[tuple[str, str], int]:
    rel = path.relative_to(REPO).as_posix()
    out: dict[tuple[str, str], int] = {}

    def visit(node: ast.AST, prefix: str, in_class: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.", True)
            elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                out[(rel, prefix + child.name)] = parameters(child, in_class)
                visit(child, f"{prefix}{child.name}.", False)
            else:
                visit(child, prefix, in_class)

    visit(tree, "", False)
    return out


def test_no_function_in_shipped_code_takes_ten_parameters_beyond_the_ones_left() -> None:
    found = {k: n for path, tree in shipped_trees() for k, n in counts(path, tree).items() if n >= LIMIT}
    new = {k: n for k, n in found.items() if k not in LEFT}
    grew = {k: (LEFT[k], n) for k, n in found.items() if k in LEFT and n > LEFT[k]}
    done = sorted(k for k in LEFT if k not in found)
    assert not new, f"take a parameter object instead: {new}"
    assert not grew, f"more parameters than before (before, now): {grew}"
    assert not done, f"under {LIMIT} now (or gone): take them out of LEFT: {done}"


def test_the_count_sees_methods_nested_functions_and_every_kind_of_parameter() -> None:
    tree = ast.parse("class A:\n    def m(self, a, /, b, *c, d, **e): pass\n"
                     "def f(a, b=1):\n    def g(x, *, y): pass\n")
    got = counts(REPO / "x.py", tree)
    assert got == {("x.py", "A.m"): 5, ("x.py", "f"): 2, ("x.py", "f.g"): 2}
