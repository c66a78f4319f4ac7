"""``riskfield.options.grouped``: a dataclass parameter of a typer command stands for its fields'
options, in place, and the command receives the dataclass built from them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import pytest
import typer
from typer.testing import CliRunner

from riskfield.options import grouped


@dataclass(frozen=True)
class Pace:
    """Two options declared once."""

    rate_hz: Annotated[float, typer.Option(help="Events per second.")] = 20.0
    names: Annotated[list[str] | None, typer.Option("--name", "-n", help="Repeatable.")] = None


def test_a_group_is_its_fields_options_in_place_and_arrives_as_one_object() -> None:
    app = typer.Typer(add_completion=False)
    got: list[tuple[int, Pace, bool]] = []

    @app.command()
    @grouped
    def main(first: Annotated[int, typer.Option(help="Before.")] = 1, pace: Pace = Pace(),
             last: Annotated[bool, typer.Option(help="After.")] = False) -> None:
        """The command's help."""
        got.append((first, pace, last))

    runner = CliRunner()
    assert runner.invoke(app, ["--rate-hz", "5", "-n", "a", "--name", "b", "--last"]).exit_code == 0
    assert got == [(1, Pace(5.0, ["a", "b"]), True)]
    assert runner.invoke(app, []).exit_code == 0
    assert got[-1] == (1, Pace(), False)
    text = runner.invoke(app, ["--help"], env={"COLUMNS": "200"}).output
    order = [text.index(s) for s in ("--first", "--rate-hz", "--name", "--last")]
    assert order == sorted(order) and "Events per second." in text and "The command's help." in text
    assert main.__name__ == "main"


def test_an_option_declared_twice_is_refused() -> None:
    with pytest.raises(TypeError, match="declared twice"):
        @grouped
        def main(rate_hz: float = 1.0, pace: Pace = Pace()) -> None:
            pass
