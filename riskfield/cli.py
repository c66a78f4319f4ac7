"""The ``riskfield`` command line."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.table import Table

from riskfield import __version__

app = typer.Typer(help="Semantic-risk safety filtering from one RGB camera, as Zenoh services.",
                  no_args_is_help=True, add_completion=False)
console = Console(stderr=True, soft_wrap=True, highlight=False)

#: ``riskfield bench NAME``: name → "module:typer_app", imported only when asked for.
BENCHES: dict[str, str] = {
    "codec": "riskfield.protocol_bench:app",
    "filter": "riskfield.services.safety_filter.bench:app",
    "mapping": "riskfield.services.mapping.bench:app",
    "latency": "riskfield.edge.latency_bench:app",
    "safety": "riskfield.services.navigator.bench_safety:app",
    "teleop": "riskfield.services.navigator.bench_teleop:app",
    "navigation": "riskfield.services.navigator.bench_navigation:app",
}


def _version(value: bool) -> None:
    if value:
        print(f"riskfield {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[Optional[bool], typer.Option("--version", callback=_version, is_eager=True,  # noqa: UP045
                                                    help="Print the version and exit.")] = None,
) -> None:
    """riskfield command line."""


Connect = Annotated[Optional[list[str]], typer.Option("--connect", "-e", help="Zenoh endpoint to connect to (repeatable).")]  # noqa: UP045,E501
Listen = Annotated[Optional[list[str]], typer.Option("--listen", "-l", help="Zenoh endpoint to listen on (repeatable).")]  # noqa: UP045,E501


def _overrides(connect, listen, mode, robot, prefix, config, log_level, sets) -> dict:
    from riskfield.services.runtime import parse_overrides

    out = parse_overrides(sets or [])
    for k, v in dict(connect=connect, listen=listen, mode=mode, robot=robot, prefix=prefix,
                     config=config, log_level=log_level).items():
        if v:
            out[k] = v
    return out


@app.command()
def run(
    service: Annotated[str, typer.Argument(help="router, mapping, safety-filter, ... (see `riskfield services`)")],
    connect: Connect = None,
    listen: Listen = None,
    mode: Annotated[Optional[str], typer.Option(help="peer, client or router.")] = None,  # noqa: UP045
    robot: Annotated[Optional[str], typer.Option(help="Robot id (key prefix part).")] = None,  # noqa: UP045
    prefix: Annotated[Optional[str], typer.Option(help="Key prefix, default rf.")] = None,  # noqa: UP045
    config: Annotated[Optional[Path], typer.Option("--config", "-c", help="YAML or TOML config file.")] = None,  # noqa: UP045
    log_level: Annotated[Optional[str], typer.Option(help="DEBUG, INFO, WARNING.")] = None,  # noqa: UP045
    set_: Annotated[Optional[list[str]], typer.Option("--set", "-s", help="Setting as key=value (repeatable).")] = None,  # noqa: UP045
    duration: Annotated[Optional[float], typer.Option(help="Stop after this many seconds.")] = None,  # noqa: UP045
) -> None:
    """Start one node in this process; Ctrl-C or SIGTERM stops it cleanly (exit code 0)."""
    from pydantic import ValidationError

    from riskfield.services.runtime import ServiceUnavailable, run_service

    try:
        code = run_service(service, _overrides(connect, listen, mode, robot, prefix, config, log_level, set_),
                           duration_s=duration)
    except ServiceUnavailable as exc:
        console.print(f"[red]{exc}[/red]")
        raise typer.Exit(2) from None
    except (ValidationError, ValueError, FileNotFoundError) as exc:
        console.print(f"[red]invalid configuration for {service}:[/red] {exc}")
        raise typer.Exit(2) from None
    except ConnectionError as exc:
        console.print(f"[red]{exc}[/red]")
        raise typer.Exit(3) from None
    raise typer.Exit(code)


@app.command()
def up(
    services: Annotated[Optional[list[str]], typer.Argument(help="Services to start beside the router.")] = None,  # noqa: UP045
    listen: Annotated[str, typer.Option(help="Endpoint of the embedded router.")] = "tcp/127.0.0.1:7447",
    router: Annotated[bool, typer.Option(help="Start the embedded router.")] = True,
    robot: Annotated[Optional[str], typer.Option()] = None,  # noqa: UP045
    prefix: Annotated[Optional[str], typer.Option()] = None,  # noqa: UP045
    config: Annotated[Optional[Path], typer.Option("--config", "-c")] = None,  # noqa: UP045
    duration: Annotated[Optional[float], typer.Option(help="Stop everything after this many seconds.")] = None,  # noqa: UP045
) -> None:
    """Start the router and services as separate processes; logs are prefixed by service."""
    from riskfield.launcher import Launcher
    from riskfield.services.runtime import SERVICES

    names = services or []
    unknown = [n for n in names if n not in SERVICES or n == "router"]
    if unknown:
        console.print(f"[red]unknown service(s): {', '.join(unknown)}[/red]")
        raise typer.Exit(2)
    common: list[str] = []
    for flag, value in (("--robot", robot), ("--prefix", prefix), ("--config", config)):
        if value:
            common += [flag, str(value)]
    launcher = Launcher()
    if router:
        launcher.add("router", ["--listen", listen, *common])
    for name in names:
        launcher.add(name, ["--connect", listen, *common])
    launcher.start()
    raise typer.Exit(launcher.wait(duration))


@app.command()
def schema(outdir: Annotated[Path, typer.Argument(help="Folder for <Name>.schema.json files.")]) -> None:
    """Export a JSON Schema per message of the wire contract."""
    from riskfield.protocol.schema import export

    for p in export(outdir):
        print(p)


@app.command()
def services() -> None:
    """List the services and whether they can start here."""
    from riskfield.services.runtime import SERVICES, ServiceUnavailable, load_service

    table = Table("service", "module", "status")
    for name, target in SERVICES.items():
        try:
            load_service(name)
            status = "[green]ok[/green]"
        except ServiceUnavailable as exc:
            status = f"[yellow]{exc}[/yellow]"
        table.add_row(name, target, status)
    Console().print(table)


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def bench(
    ctx: typer.Context,
    name: Annotated[str, typer.Argument(help=f"One of: {', '.join(BENCHES)}.")],
) -> None:
    """Run a benchmark (pass --help after its name for its options)."""
    target = BENCHES.get(name)
    if target is None:
        console.print(f"[red]unknown benchmark {name!r}; known: {', '.join(BENCHES)}[/red]")
        raise typer.Exit(2)
    module, attr = target.split(":")
    try:
        sub = getattr(importlib.import_module(module), attr)
    except ModuleNotFoundError as exc:
        console.print(f"[red]benchmark {name!r} is not available: {exc}[/red]")
        raise typer.Exit(2) from None
    sub(list(ctx.args), prog_name=f"riskfield bench {name}", standalone_mode=True)


if __name__ == "__main__":  # pragma: no cover
    app(sys.argv[1:])
