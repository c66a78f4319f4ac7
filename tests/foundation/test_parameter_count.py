"""No function in shipped code takes ten parameters or more, compiled kernels included: parameter
objects instead, and compiled kernels their arrays through a workspace (``protocol.kernels.Layout``) or
tuples grouped by role."""

from __future__ import annotations

import ast
from pathlib import Path

from .test_platforms import REPO, shipped_trees

LIMIT = 10


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


def test_no_function_in_shipped_code_takes_ten_parameters() -> None:
    found = {k: n for path, tree in shipped_trees() for k, n in counts(path, tree).items() if n >= LIMIT}
    assert not found, f"take a parameter object instead: {found}"


def test_the_count_sees_methods_nested_functions_and_every_kind_of_parameter() -> None:
    tree = ast.parse("class A:\n    def m(self, a, /, b, *c, d, **e): pass\n"
                     "def f(a, b=1):\n    def g(x, *, y): pass\n")
    got = counts(REPO / "x.py", tree)
    assert got == {("x.py", "A.m"): 5, ("x.py", "f"): 2, ("x.py", "f.g"): 2}
