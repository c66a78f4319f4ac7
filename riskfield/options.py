"""Typer options declared once, as the fields of a dataclass, and handed to a command as one object.

typer builds a command's options from its function's parameters and has no parameter object of
its own (fastapi/typer issues 154 and 264). :func:`grouped` fills that in: a command parameter
annotated with an option-group dataclass stands for that dataclass's fields, each an ``Annotated``
typer option with its default, in their order and at the parameter's place; the command receives
the dataclass built from them. The options, their help and their order are exactly as if the
fields were the command's own parameters.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import typing
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


def _is_group(annotation: Any) -> bool:
    return isinstance(annotation, type) and dataclasses.is_dataclass(annotation)


def _fields(group: type) -> list[inspect.Parameter]:
    hints = typing.get_type_hints(group, include_extras=True)  # in the module that declares the group
    out = []
    for f in dataclasses.fields(group):
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = inspect.Parameter.empty
        out.append(inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=hints[f.name]))
    return out


def grouped(command: F) -> F:
    """``command`` with each parameter whose annotation is a dataclass replaced, for typer, by that
    dataclass's fields (see module doc). Put it under ``@app.command()``."""
    signature = inspect.signature(command, eval_str=True)
    parameters: list[inspect.Parameter] = []
    groups: dict[str, tuple[type, list[str]]] = {}
    for p in signature.parameters.values():
        if _is_group(p.annotation):
            fields = _fields(p.annotation)
            groups[p.name] = (p.annotation, [f.name for f in fields])
            parameters += fields
        else:
            parameters.append(p.replace(kind=inspect.Parameter.KEYWORD_ONLY))  # typer passes keywords only
    names = [p.name for p in parameters]
    if len(set(names)) != len(names):
        raise TypeError(f"{command.__name__}: an option declared twice among {names}")

    @functools.wraps(command)
    def wrapper(**kwargs: Any) -> Any:
        for name, (group, fields) in groups.items():
            kwargs[name] = group(**{f: kwargs.pop(f) for f in fields})
        return command(**kwargs)

    # typer reads these (inspect.signature stops at __signature__ before following __wrapped__)
    wrapper.__signature__ = signature.replace(parameters=parameters)  # type: ignore[attr-defined]
    wrapper.__annotations__ = {p.name: p.annotation for p in parameters}
    return typing.cast(F, wrapper)
