"""The ``riskfield`` command line."""

from __future__ import annotations

import dataclasses
import functools
import importlib
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from riskfield import __version__
from riskfield.options import grouped

if TYPE_CHECKING:
    from riskfield.services.runtime.processes import RestartPolicy
    from riskfield.services.runtime.settings import KnownSettings

app = typer.Typer(help="Semantic-risk safety filtering from one RGB camera, as Zenoh services.",
                  no_args_is_help=True, add_completion=False)
console = Console(stderr=True, soft_wrap=True, highlight=False)


def _missing_extras_in_one_line(command: Callable[..., Any]) -> Callable[..., Any]:
    """A command whose missing optional dependency (``MODULE_EXTRAS``) ends in one line
    naming the extra to install, exit code 2, instead of a traceback."""

    @functools.wraps(command)  # typer reads the signature through __wrapped__
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except ModuleNotFoundError as exc:
            from riskfield.services.runtime.service import missing_extra

            line = missing_extra(exc)
            if line is None:
                raise
            console.print(f"[red]{escape(line)}[/red]")
            raise typer.Exit(2) from None

    return wrapper


#: ``riskfield bench NAME`` runs ``riskfield.experiments.benches.NAME:app``, imported only when asked for.
BENCHES: tuple[str, ...] = ("codec", "filter", "mapping", "latency", "safety", "teleop", "navigation", "sim",
                            "perception", "crowd", "startup", "link", "scale")

#: ``riskfield up --profile NAME``: one site's services, beside its router. ``robot`` is the robot
#: computer (the camera, the LIMO bridge, the joystick gateway and the filter, as docker-compose.yml's
#: ``robot`` profile); perception and mapping run on the server (``server``), whose router the robot's
#: router dials (``--server``).
UP_PROFILES: dict[str, tuple[str, ...]] = {
    "robot": ("camera", "limo", "joystick", "safety-filter"),
    "server": ("perception", "mapping"),
}


def _version(value: bool) -> None:
    if value:
        print(f"riskfield {__version__}")
        raise typer.Exit()


def every_service_settings() -> KnownSettings:
    """What every service ``riskfield run`` knows accepts, for the keys of a file or environment
    shared by a stack (``runtime.settings.know_other_services``). Importing every service is this
    layer's business, not the runtime's; it happens only when a node meets a key not its own."""
    from riskfield.services.runtime import SERVICES, load_service
    from riskfield.services.runtime.settings import KnownSettings

    settings: dict[str, Any] = {}
    for name in SERVICES:
        try:
            # its settings load without its runtime packages: a key stays checked where it can't run
            settings[name] = load_service(name, runnable=False).settings
        except Exception:  # a missing extra, or a native library that fails to load
            settings[name] = None
    return KnownSettings.of(settings)


@app.callback()
def main(
    version: Annotated[bool | None, typer.Option("--version", callback=_version, is_eager=True,
                                                    help="Print the version and exit.")] = None,
) -> None:
    """riskfield command line."""
    from riskfield.services.runtime.settings import know_other_services

    know_other_services(every_service_settings)


#: The one ``--connect`` of every command (the argparse tools: ``runtime.session.add_connect_argument``).
Connect = Annotated[list[str] | None, typer.Option("--connect", "-e", help="Zenoh endpoint to dial (repeatable).")]
Listen = Annotated[list[str] | None, typer.Option("--listen", "-l", help="Zenoh endpoint to listen on (repeatable).")]
#: The robot and key prefix of ``riskfield up`` and the tools (``riskfield run``'s, with help: :class:`NodeOptions`).
Robot = Annotated[str | None, typer.Option()]
Prefix = Annotated[str | None, typer.Option()]


@dataclass(frozen=True)
class NodeOptions:
    """``riskfield run``'s settings of the node beside its config file: how it connects, which robot
    and key prefix it serves, its config file, log level and ``--set`` overrides."""

    connect: Connect = None
    listen: Listen = None
    mode: Annotated[str | None, typer.Option(help="peer, client or router.")] = None
    robot: Annotated[str | None, typer.Option(help="Robot id (key prefix part).")] = None
    prefix: Annotated[str | None, typer.Option(help="Key prefix, default rf.")] = None
    config: Annotated[Path | None, typer.Option("--config", "-c", help="YAML or TOML config file.")] = None
    log_level: Annotated[str | None, typer.Option(help="DEBUG, INFO, WARNING.")] = None
    set_: Annotated[list[str] | None, typer.Option("--set", "-s", help="Setting as key=value (repeatable).")] = None

    def overrides(self) -> dict:
        """The node's settings these give: the ``--set`` pairs, then each named option given."""
        from riskfield.services.runtime import parse_overrides

        out = parse_overrides(self.set_ or [])
        for k in ("connect", "listen", "mode", "robot", "prefix", "config", "log_level"):
            if v := getattr(self, k):
                out[k] = v
        return out


@dataclass(frozen=True)
class Site:
    """The router a tool dials and the robot and key prefix whose keys it reads."""

    connect: Connect = None
    robot: Robot = None
    prefix: Prefix = None


@dataclass(frozen=True)
class StackIdentity:
    """The robot and key prefix of every service ``riskfield up`` starts, and their config file."""

    robot: Robot = None
    prefix: Prefix = None
    config: Annotated[Path | None, typer.Option("--config", "-c")] = None


@dataclass(frozen=True)
class Restarts:
    """How ``riskfield up`` restarts a crashed service (``runtime.processes.RestartPolicy``)."""

    restart: Annotated[bool, typer.Option(help="Restart a crashed service with back-off (--no-restart: stop "
                                          "the whole stack at the first exit, exit code 1, for tests and CI).")
                       ] = True
    max_restarts: Annotated[int, typer.Option(min=0, help="Crashes in a row (without a healthy run) a service may "
                                              "have before the stack stops with exit code 1; 0: no limit.")] = 10
    backoff: Annotated[float, typer.Option(min=0.01, help="First restart delay (s), doubled on each crash in a "
                                           "row.")] = 0.5
    backoff_max: Annotated[float, typer.Option(min=0.01, help="Longest restart delay (s).")] = 30.0
    healthy: Annotated[float, typer.Option(min=0.01, help="Seconds a restarted service must run to count as "
                                           "healthy again (back-off and budget reset).")] = 30.0

    def policy(self) -> RestartPolicy:
        """The policy; ValueError for delays it refuses."""
        from riskfield.services.runtime.processes import NO_RESTART, RestartPolicy

        if not self.restart:
            return NO_RESTART
        return RestartPolicy(backoff_s=self.backoff, backoff_max_s=self.backoff_max, healthy_s=self.healthy,
                             max_restarts=self.max_restarts)


@app.command(add_help_option=False)
@grouped
def run(
    ctx: typer.Context,
    service: Annotated[str | None, typer.Argument(
        help="router, mapping, safety-filter, ... (see `riskfield services`)", show_default=False)] = None,
    node: NodeOptions = NodeOptions(),
    duration: Annotated[float | None, typer.Option(help="Stop after this many seconds.")] = None,
    help_: Annotated[bool, typer.Option("--help", "-h", help="Show this message (with SERVICE: its settings) "
                                        "and exit.")] = False,
) -> None:
    """Start one node in this process; Ctrl-C or SIGTERM stops it cleanly (exit code 0)."""
    from pydantic import ValidationError

    from riskfield.services.runtime import ServiceUnavailable, UnknownSetting, run_service

    if help_:
        typer.echo(ctx.get_help())
        if service is not None:
            _print_settings(service)
        raise typer.Exit(0)
    if service is None:
        console.print("[red]missing SERVICE: riskfield run SERVICE (see `riskfield services`)[/red]")
        raise typer.Exit(2)
    try:
        code = run_service(service, node.overrides(), duration_s=duration)
    except (ServiceUnavailable, UnknownSetting) as exc:
        console.print(f"[red]{escape(str(exc))}[/red]")
        raise typer.Exit(2) from None
    except (ValidationError, ValueError, FileNotFoundError) as exc:
        console.print(f"[red]invalid configuration for {escape(service)}:[/red] {escape(str(exc))}")
        raise typer.Exit(2) from None
    except ConnectionError as exc:
        console.print(f"[red]{escape(str(exc))}[/red]")
        raise typer.Exit(3) from None
    raise typer.Exit(code)


def _print_settings(service: str) -> None:
    """The settings of one service from its settings model: its own first, then the ones every
    node shares, each with its type, bounds, default and description (``riskfield.settings_help``)."""
    from riskfield.services.runtime import ServiceUnavailable, load_service
    from riskfield.services.runtime.settings import NodeSettings
    from riskfield.settings_help import setting_lines

    try:
        spec = load_service(service, runnable=False)  # its settings, even where it cannot run
    except ServiceUnavailable as exc:
        console.print(f"[yellow]{escape(str(exc))}[/yellow]")
        return
    # One line per setting (not a table), so that a narrow terminal or grep keeps each whole.
    print(f"\n{service} settings (--set key=value, the {service} section of a config file, or RISKFIELD_<KEY>):")
    common = NodeSettings.model_fields
    for line in setting_lines(spec.settings, skip=common):
        print(line)
    print("\ncommon to every node:")
    for line in setting_lines(spec.settings, skip=set(spec.settings.model_fields) - set(common)):
        print(line)


@app.command()
@grouped
def up(
    services: Annotated[list[str] | None, typer.Argument(help="Services to start beside the router.")] = None,
    profile: Annotated[str | None, typer.Option(help="A site's services (added to SERVICES): "
                                                + "; ".join(f"{k}: {' '.join(v)}" for k, v in UP_PROFILES.items())
                                                + ".")] = None,
    listen: Annotated[str, typer.Option(help="Endpoint of the embedded router.")] = "tcp/127.0.0.1:7447",
    router: Annotated[bool, typer.Option(help="Start the embedded router.")] = True,
    server: Annotated[str | None, typer.Option(help="The server site's router, which the embedded router dials "
                                               "(e.g. tcp/10.0.0.2:7447): the robot profile's link.")] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="The LIMO bridge drives the real serial port with "
                                          "stop frames only and counts the commands it withheld (bring-up).")
                       ] = False,
    stack: StackIdentity = StackIdentity(),
    duration: Annotated[float | None, typer.Option(help="Stop everything after this many seconds.")] = None,
    restarts: Restarts = Restarts(),
) -> None:
    """Start the router and services as separate processes; logs are prefixed by service.

    A crashed service is restarted after a back-off (one log line each time) while the others keep
    running. Ctrl-C or SIGTERM stops them all: exit code 0 if all stopped cleanly, 1 if any ended
    badly. Exit code 1 also when a service exhausts its restart budget or has a configuration
    error (exit code 2 is never restarted), and with --no-restart as soon as a service exits."""
    from riskfield.protocol import Keys
    from riskfield.services.runtime import SERVICES, NodeSettings
    from riskfield.services.runtime.processes import ProcessRunner

    if profile is not None and profile not in UP_PROFILES:
        console.print(f"[red]unknown profile {escape(profile)!r}: use one of {', '.join(UP_PROFILES)}[/red]")
        raise typer.Exit(2)
    site = UP_PROFILES[profile] if profile else ()
    names = [*site, *(n for n in services or [] if n not in site)]
    unknown = [n for n in names if n not in SERVICES or n == "router"]
    if dry_run and "limo" not in names:
        console.print("[red]--dry-run is the LIMO bridge's: add limo (or --profile robot)[/red]")
        raise typer.Exit(2)
    if unknown:
        from riskfield.services.runtime.service import unknown_service

        console.print(f"[red]{escape('; '.join(unknown_service(n) for n in unknown))}[/red]")
        raise typer.Exit(2)
    robot, prefix, config = stack.robot, stack.prefix, stack.config
    common: list[str] = []
    for flag, value in (("--robot", robot), ("--prefix", prefix), ("--config", config)):
        if value:
            common += [flag, str(value)]
    try:  # the robot whose liveliness tokens say "ready", resolved as the services resolve it
        ident = NodeSettings(**{k: v for k, v in dict(robot=robot, prefix=prefix, config=config).items() if v})
        keys = Keys(robot=ident.robot, prefix=ident.prefix)
    except (ValueError, OSError):  # a broken config: the services will say so and exit, and so will we
        keys = Keys(robot=robot or "limo1", prefix=prefix or "rf")
    try:
        policy = restarts.policy()
    except ValueError as exc:
        console.print(f"[red]{escape(str(exc))}[/red]")
        raise typer.Exit(2) from None
    runner = ProcessRunner(listen, keys, echo=True, console=console, restart=policy)
    if router:
        runner.add("router", "router", [*common, *(["--connect", server] if server else [])])
    for name in names:
        runner.add(name, name, [*common, *(["--set", "dry_run=true"] if dry_run and name == "limo" else [])])
    raise typer.Exit(runner.watch(duration))


def _run_tool(service: str, overrides: dict, duration: float | None) -> None:
    from riskfield.services.runtime import ServiceUnavailable, run_service

    try:
        code = run_service(service, {k: v for k, v in overrides.items() if v is not None}, duration_s=duration)
    except (ServiceUnavailable, FileNotFoundError, ValueError, ConnectionError) as exc:
        console.print(f"[red]{escape(str(exc))}[/red]")
        raise typer.Exit(2) from None
    raise typer.Exit(code)


@app.command()
@grouped
def record(
    out: Annotated[Path, typer.Option(help="Folder for recording.mcap and summary.json; an earlier run there "
                                      "is kept: this one is recording-1.mcap, summary-1.json, ...")] = Path(
                                          "out/record"),
    keys: Annotated[str | None, typer.Option(help="Key expression (default: every key of the robot).")] = None,
    raw: Annotated[bool, typer.Option("--raw", help="Also keep the wire bytes of every key (pointmaps and images "
                                      "too), so `riskfield replay` can reproduce all of them.")] = False,
    include: Annotated[list[str] | None, typer.Option(help="Record only keys matching this key expression, "
                                                      "full or relative to the robot (repeatable), e.g. 'map/**'.")
                       ] = None,
    exclude: Annotated[list[str] | None, typer.Option(help="Skip keys matching this key expression "
                                                      "(repeatable), e.g. 'sim/**'.")] = None,
    max_mb: Annotated[float, typer.Option(help="Stop recording at this total size (MB); 0: no limit.")] = 0.0,
    split_mb: Annotated[float, typer.Option(help="Continue in a new file past this size (MB); 0: one file.")] = 0.0,
    site: Site = Site(),
    duration: Annotated[float | None, typer.Option(help="Stop after this many seconds.")] = None,
) -> None:
    """Record a robot's keys to MCAP that Foxglove (and any MCAP tool) can show: camera as
    CompressedImage, ESDF as Grid/VoxelGrid, pointmaps as PointCloud, state as FrameTransform,
    the rest as JSON. The keys that drive the filter (map/esdf, state, cmd/ref, nav/goal) are
    also kept raw for `riskfield replay`; --raw keeps every key raw."""
    _run_tool("record", dict(out=out, keys=keys, raw=raw, include=include or None, exclude=exclude or None,
                             max_mb=max_mb, split_mb=split_mb, **dataclasses.asdict(site)), duration)


@app.command()
def replay(
    file: Annotated[Path, typer.Argument(help="A recording.mcap made by `riskfield record`.")],
    speed: Annotated[float, typer.Option(help="Time scale: 2 replays twice as fast.")] = 1.0,
    loop: Annotated[bool, typer.Option(help="Start again at the end.")] = False,
    remap_from: Annotated[str | None, typer.Option(help="Key prefix to rewrite, e.g. rf/limo1.")] = None,
    remap_to: Annotated[str | None, typer.Option(help="New key prefix, e.g. rf/replay1.")] = None,
    include_commands: Annotated[bool, typer.Option(
        "--include-commands", help="Also publish cmd/safe, cmd/ref and nav/goal (can drive a live robot).")] = False,
    include_state: Annotated[bool, typer.Option(
        "--include-state", help="Also publish state and state/relocalise (moves a live robot's map and "
        "misleads its filter).")] = False,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="List what would be published, then exit.")] = False,
    connect: Connect = None,
) -> None:
    """Publish a recording's raw channels back with their original timing. Command keys are
    withheld unless --include-commands, the robot's state unless --include-state; keys recorded
    only as views are listed as not reproducible.
    Exit codes: 0 played, 1 the file was cut short or corrupt (what was readable was played),
    2 not a recording or a bad option."""
    from rich.markup import escape

    from riskfield.services.recorder.mcap_io import RecordingError, check_recording, scan
    from riskfield.services.recorder.replay import Remap, plan

    try:
        check_recording(file)
        remap = Remap(remap_from, remap_to)
        keys, err = scan(file)
        p = plan(keys, remap, include_commands=include_commands, include_state=include_state)
    except (RecordingError, ValueError) as exc:
        console.print(f"[red]{escape(str(exc))}[/red]")
        raise typer.Exit(2) from None
    for line in p.lines() if dry_run else [ln for ln in p.lines() if not ln.startswith("publish")]:
        console.print(escape(line))
    if dry_run:
        if err is not None:
            console.print(f"[yellow]{escape(str(err))}[/yellow]")
        raise typer.Exit(1 if err is not None else 0)
    if not p.publish:
        console.print("[red]nothing to replay: no raw channel to publish[/red]")
        raise typer.Exit(2)
    from riskfield.services.recorder.node import LAST_REPLAY
    from riskfield.services.runtime import ServiceUnavailable, run_service

    overrides = dict(file=file, speed=speed, loop=loop, remap_from=remap_from, remap_to=remap_to,
                     include_commands=include_commands, include_state=include_state, connect=connect, verify=False)
    try:
        code = run_service("replay", {k: v for k, v in overrides.items() if v is not None})
    except (ServiceUnavailable, FileNotFoundError, ValueError, ConnectionError) as exc:
        console.print(f"[red]{escape(str(exc))}[/red]")
        raise typer.Exit(2) from None
    replayer = LAST_REPLAY.get("replayer")
    if replayer is not None and replayer.error is not None:  # already said in one log line by the replayer
        code = code or replayer.exit_code
    raise typer.Exit(code)


@app.command()
@grouped
def view(
    foxglove: Annotated[bool, typer.Option("--foxglove", help="Serve the live stack to Foxglove over its WebSocket "
                                           "protocol (layout: deploy/foxglove/riskfield-layout.json) instead of "
                                           "streaming it to Rerun.")] = False,
    host: Annotated[str, typer.Option(help="--foxglove: address to bind (0.0.0.0 for other machines).")
                    ] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="--foxglove: TCP port of the WebSocket server (0: any free one).")
                    ] = 8765,
    live: Annotated[bool, typer.Option(help="Rerun: open the viewer (the web viewer when headless).")] = True,
    out: Annotated[Path | None, typer.Option(help="Rerun: folder for view.rrd.")] = None,
    write_layout: Annotated[Path | None, typer.Option(
        help="--foxglove: write the Foxglove layout for this robot and prefix to this file, then exit.")] = None,
    site: Site = Site(),
    duration: Annotated[float | None, typer.Option(help="Stop after this many seconds.")] = None,
) -> None:
    """Watch a running stack live: in Rerun (the `viewer` service), or with --foxglove in Foxglove
    (the `foxglove` service: camera, ESDF grid, point cloud, robot footprint, tracked people with
    velocity arrows, and the filter's intervention and its reason)."""
    common = dataclasses.asdict(site)
    if foxglove and write_layout is not None:
        import json

        from riskfield.protocol import Keys

        try:
            from riskfield.services.recorder.live import layout

            text = json.dumps(layout(Keys(site.robot or "limo1", site.prefix or "rf").root), indent=2) + "\n"
        except ModuleNotFoundError as exc:
            from riskfield.services.runtime.service import missing_extra

            console.print(f"[red]{escape(missing_extra(exc) or str(exc))}[/red]")
            raise typer.Exit(2) from None
        write_layout.write_text(text)
        console.print(f"wrote {write_layout}: import it in Foxglove (Layouts → Import from file)")
        raise typer.Exit(0)
    if foxglove:
        _run_tool("foxglove", dict(common, host=host, port=port), duration)
    _run_tool("viewer", dict(common, live=live, out=out), duration)


@app.command()
@_missing_extras_in_one_line
def demo(
    out: Annotated[Path, typer.Option(help="Report folder: summary.json, plots, recording.mcap, logs.")] = Path(
        "out/demo"),
    live: Annotated[bool, typer.Option(help="Open a live Rerun view (web viewer when headless).")] = False,
    foxglove: Annotated[bool, typer.Option(
        "--foxglove", help="Serve the stack live to Foxglove on ws://127.0.0.1:8765 (extra foxglove); the "
        "layout for the demo's robot is written to --out.")] = False,
    seed: Annotated[int, typer.Option(help="Seed of the scripted operator.")] = 0,
    budget: Annotated[float, typer.Option(help="Seconds allowed for both experiments after start-up.")] = 100.0,
    verbose: Annotated[bool, typer.Option(help="Echo every service's log lines.")] = False,
    report_only: Annotated[bool, typer.Option(help="Only rebuild the report from a finished run in --out.")] = False,
    perception: Annotated[str, typer.Option(help="Perception geometry: sim (degraded truth, keyframes) or rgbd "
                                            "(the simulator's depth + odometry, one class).")] = "sim",
) -> None:
    """The whole stack on this machine: teleop towards a ball and a dog, then a navigation loop
    with an unseen obstacle; ends with a summary table and a report folder."""
    import json

    from riskfield.experiments.demo.report import make_report
    from riskfield.experiments.demo.run import Demo, DemoConfig

    if perception not in ("sim", "rgbd"):
        console.print(f"[red]--perception {perception!r}: use sim or rgbd[/red]")
        raise typer.Exit(2)
    if foxglove:
        import foxglove as _  # noqa: F401  a missing extra ends here, in one line, before the stack starts
    cfg = DemoConfig(out=out, live=live, foxglove=foxglove, seed=seed, budget_s=budget, verbose=verbose,
                     perception=perception)
    if report_only:
        phases = out / "phases.json"
        if not phases.is_file():
            console.print(f"[red]{phases} does not exist: run the demo first[/red]")
            raise typer.Exit(2)
        cfg.phases = json.loads(phases.read_text())
        summary = make_report(cfg, console)
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        raise typer.Exit(0)
    raise typer.Exit(Demo(cfg, console).run())


@app.command()
def warmup(
    services: Annotated[list[str] | None, typer.Argument(
        help="Services whose kernels to compile (default: every service that has kernels).", show_default=False)
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Start every service's set-up even when the cache "
                                        "stamp says it is done.")] = False,
) -> None:
    """Compile the numba kernels the nodes load at start, once, into the cache they load them from
    (NUMBA_CACHE_DIR, else __pycache__ next to the sources): a node's first start is then as fast as
    its second. Cheap when already done; `make setup` runs it, and so can a Dockerfile."""
    from riskfield.services.runtime import ServiceUnavailable
    from riskfield.services.runtime.warmup import warm_up

    try:
        warm_up(services, force=force, say=lambda line: console.print(escape(line)))
    except ServiceUnavailable as exc:
        console.print(f"[red]{escape(str(exc))}[/red]")
        raise typer.Exit(2) from None


Robots = Annotated[list[str] | None, typer.Option("--robot", "-r", help="Robot id (repeatable); default limo1.")]


@app.command()
def acl(
    robot: Robots = None,
    prefix: Annotated[str, typer.Option(help="Key prefix.")] = "rf",
    out: Annotated[Path | None, typer.Option("--out", "-o", help="File to write; default: print.")] = None,
) -> None:
    """The secure routers' config with its access control, generated from protocol/keys.py."""
    from riskfield.services.runtime.acl import router_config

    try:
        text = router_config(robot or ["limo1"], prefix)
    except ValueError as exc:
        console.print(f"[red]{escape(str(exc))}[/red]")
        raise typer.Exit(2) from None
    if out is None:
        sys.stdout.write(text)
    else:
        out.write_text(text)
        console.print(f"acl: {out}")


@app.command()
def secrets(
    robot: Robots = None,
    prefix: Annotated[str, typer.Option(help="Key prefix.")] = "rf",
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder for users, certificates and the ACL.")] = Path(
        "deploy/secrets"),
    certs: Annotated[bool, typer.Option(help="Also make the certificates (needs openssl).")] = True,
) -> None:
    """Per-robot identities: passwords (mode 0600), certificates and the routers' access control."""
    import subprocess

    from riskfield.services.runtime.acl import make_secrets

    try:
        made = make_secrets(out, robot or ["limo1"], prefix, certs=certs)
    except (ValueError, FileNotFoundError) as exc:
        console.print(f"[red]{escape(str(exc))}[/red]")
        raise typer.Exit(2) from None
    except subprocess.CalledProcessError as exc:
        console.print(f"[red]{escape(' '.join(exc.cmd[:2]))} failed: {escape(exc.stderr or '')}[/red]")
        raise typer.Exit(1) from None
    for path in made:
        console.print(f"secrets: {path}")


@app.command()
def schema(outdir: Annotated[Path, typer.Argument(help="Folder for <Name>.schema.json files.")]) -> None:
    """Export a JSON Schema per message of the wire contract."""
    from riskfield.protocol.schema import export

    for p in export(outdir):
        print(p)


@app.command()
def services() -> None:
    """List the services, the extra each needs and whether it can start here."""
    from riskfield.services.runtime import SERVICES, ServiceUnavailable, load_service
    from riskfield.services.runtime.service import EXTRAS

    table = Table("service", "extra", "status")
    for name in SERVICES:
        try:
            load_service(name)
            status = "[green]ok[/green]"
        except ServiceUnavailable as exc:  # the hint holds [brackets]: escaped, not markup
            status = f"[yellow]{escape(str(exc))}[/yellow]"
        extra = EXTRAS.get(name)
        table.add_row(name, escape(f"riskfield[{extra}]") if extra else "(base)", status)
    Console(soft_wrap=True).print(table)


# The names in the command's own help: every typer shows that (an argument's help is not rendered
# by typer 0.16, the lowest allowed).
@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True}, add_help_option=False,
             help=f"Run a benchmark, one of: {', '.join(BENCHES)}. `riskfield bench NAME --help` lists "
                  "that benchmark's options.")
@_missing_extras_in_one_line
def bench(
    ctx: typer.Context,
    name: Annotated[str | None, typer.Argument(help=f"One of: {', '.join(BENCHES)}.", show_default=False)] = None,
) -> None:
    if name is None or name in ("--help", "-h"):
        typer.echo(ctx.get_help())
        raise typer.Exit(0)
    if name not in BENCHES:
        console.print(f"[red]unknown benchmark {escape(repr(name))}; known: {', '.join(BENCHES)}[/red]")
        raise typer.Exit(2)
    from riskfield.services.runtime.service import missing_extra

    try:
        sub = importlib.import_module(f"riskfield.experiments.benches.{name}").app
    except ModuleNotFoundError as exc:
        if missing_extra(exc) is not None:
            raise  # one line naming the extra, from the decorator
        console.print(f"[red]benchmark {name!r} is not available: {escape(str(exc))}[/red]")
        raise typer.Exit(2) from None
    sub(list(ctx.args), prog_name=f"riskfield bench {name}", standalone_mode=True)


if __name__ == "__main__":  # pragma: no cover
    app(sys.argv[1:])
