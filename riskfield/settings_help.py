"""The settings of a service as ``riskfield run SERVICE --help`` prints them: one line per
setting with a readable type, its bounds, its default and the first sentence of its description.

pydantic keeps a constrained type as ``Annotated[float, FieldInfo(...)]`` and a field's bounds in
``FieldInfo.metadata`` (``annotated_types.Gt`` and friends); printed as they are, a tuple of three
positive floats is a line of ``FieldInfo(annotation=None, required=True, metadata=[Gt(gt=0), ...``.
"""

from __future__ import annotations

import types
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

#: annotated_types' bound attributes → how a bound reads.
_BOUNDS = (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="), ("min_length", "len >="),
           ("max_length", "len <="), ("multiple_of", "multiple of"))


def bounds(metadata: list[Any]) -> list[str]:
    """``[Gt(gt=0), Le(le=200)]`` → ``["> 0", "<= 200"]`` (``AllowInfNan`` and the like say nothing)."""
    out = []
    for m in metadata:
        for attr, sign in _BOUNDS:
            value = getattr(m, attr, None)
            if value is not None:
                out.append(f"{sign} {value:g}" if isinstance(value, float) else f"{sign} {value}")
    return out


def type_text(annotation: Any) -> str:
    """A type as one would write it: ``tuple[float, float, float]``, ``'2d' | '3d'``, ``Path | None``."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        inner = type_text(args[0])
        limits = [b for meta in args[1:] for b in bounds(getattr(meta, "metadata", [meta]))]
        return f"{inner} ({', '.join(limits)})" if limits else inner
    if origin is Literal:
        return " | ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(type_text(a) for a in args)
    if annotation is type(None):
        return "None"
    if origin is not None:
        name = getattr(origin, "__name__", str(origin))
        parts = ["..." if a is Ellipsis else type_text(a) for a in args]
        return f"{name}[{', '.join(parts)}]" if parts else name
    if isinstance(annotation, type):
        return annotation.__name__
    return str(annotation).replace("typing.", "")


def default_text(field: FieldInfo) -> str:
    if field.default_factory is not None:
        value = field.get_default(call_default_factory=True)
    else:
        value = field.default
        if value is PydanticUndefined:
            return "(required)"
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, BaseModel):
        return f"{type(value).__name__}(...)"
    return repr(value)


_ABBREVIATIONS = ("e.g.", "i.e.", "vs.", "etc.", "cf.", "approx.", "eq.", "Eq.", "Fig.", "no.")


def first_sentence(text: str) -> str:
    """Up to the first full stop outside brackets that ends a sentence (not ``e.g.`` or ``0.5``)."""
    depth = 0
    for i, ch in enumerate(text):
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth = max(depth - 1, 0)
        elif ch == "." and depth == 0 and (i + 1 == len(text) or text[i + 1] == " "):
            if not text[: i + 1].endswith(_ABBREVIATIONS):
                return text[:i]
    return text


def summary(description: str | None, width: int = 160) -> str:
    """The first sentence of a description (its first paragraph, on one line), cut at ``width``."""
    if not description:
        return ""
    first = first_sentence(" ".join(description.strip().split("\n\n")[0].split()))
    return first if len(first) <= width else first[: width - 1].rstrip() + "…"


def setting_line(name: str, field: FieldInfo) -> str:
    """``name: type (bounds) = default  — summary``."""
    limits = bounds(field.metadata)
    kind = type_text(field.annotation) + (f" ({', '.join(limits)})" if limits else "")
    about = summary(field.description)
    return f"  {name}: {kind} = {default_text(field)}" + (f"  — {about}" if about else "")


def setting_lines(model: type[BaseModel], skip: typing.Container[str] = ()) -> Iterator[str]:
    """One line per field of ``model`` not in ``skip``; a nested model's fields follow it, dotted
    (``nav.k_rho``), as ``--set`` names them."""
    for name, field in model.model_fields.items():
        if name in skip:
            continue
        yield setting_line(name, field)
        sub = field.annotation
        if isinstance(sub, type) and issubclass(sub, BaseModel):
            for inner, inner_field in sub.model_fields.items():
                yield "  " + setting_line(f"{name}.{inner}", inner_field)
