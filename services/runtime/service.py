"""How a service declares itself, and the one function that runs any of them.

A service module exposes ``SERVICE = ServiceSpec(name, Settings, setup)``. ``setup(node,
settings)`` builds the pure core, declares subscriptions and timers on the node and may
return an object with ``close()`` (called after the loop ends).
"""

from __future__ import annotations

import difflib
import importlib
import importlib.util
import os
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .logs import StartupReport, process_age_s, setup_logging
from .node import Node, compile_watch
from .settings import NodeSettings
from .signals import catch_stop_signals

#: Service name → "module:attribute" of its ServiceSpec, imported only when started.
SERVICES: dict[str, str] = {
    "router": "riskfield.services.runtime.router:SERVICE",
    "relay": "riskfield.services.relay.node:SERVICE",
    "perception": "riskfield.services.perception.node:SERVICE",
    "mapping": "riskfield.services.mapping.node:SERVICE",
    "safety-filter": "riskfield.services.safety_filter.node:SERVICE",
    "navigator": "riskfield.services.navigator.node:SERVICE",
    "simulator": "riskfield.services.simulator.node:SERVICE",
    "camera": "riskfield.services.camera.node:SERVICE",
    "limo": "riskfield.edge.limo.node:SERVICE",
    "joystick": "riskfield.edge.joystick.node:SERVICE",
    "mavlink": "riskfield.edge.mavlink.node:SERVICE",
    "record": "riskfield.services.recorder.node:RECORD",
    "foxglove": "riskfield.services.recorder.live:SERVICE",
    "replay": "riskfield.services.recorder.node:REPLAY",
    "ros2-bridge": "riskfield.services.ros2_bridge.node:SERVICE",
    "viewer": "riskfield.services.viewer.node:SERVICE",
    "operator": "riskfield.services.operator.node:SERVICE",
    "keyboard": "riskfield.edge.joystick.keyboard:SERVICE",
}

#: The pip extra each service needs beyond the base install.
EXTRAS: dict[str, str] = {
    "perception": "sim",
    "mapping": "mapping",
    "safety-filter": "robot",
    "simulator": "sim",
    "camera": "camera",
    "limo": "robot",
    "joystick": "robot",
    "mavlink": "robot",
    "record": "tools",
    "foxglove": "foxglove",
    "replay": "tools",
    "viewer": "viz",
    "ros2-bridge": "ros2",
}


#: Optional third-party module (top-level import name) → the pip extra that installs it: the
#: one table every "install riskfield[X]" hint reads (pyproject.toml lists the extras).
MODULE_EXTRAS: dict[str, str] = {
    "rerun": "viz",
    "mcap": "tools",
    "mcap_protobuf": "tools",
    "foxglove_schemas_protobuf": "tools",
    "foxglove": "foxglove",
    "matplotlib": "tools",
    "serial": "robot",
    "pymavlink": "robot",
    "evdev": "robot",
    "numba": "robot",
    "edt": "dev",  # the ESDF tests' oracle only (tests/oracles/esdf.py)
    "open3d": "sim",
    "PIL": "sim",
    "torch": "perception",
    "rosbags": "ros2",
    "scipy": "robot",
    "av": "camera",
}

#: Modules a service imports only once it runs (so that importing its module stays cheap):
#: checked before it starts and by ``riskfield services``.
RUNTIME_NEEDS: dict[str, tuple[str, ...]] = {"viewer": ("rerun",), "foxglove": ("foxglove",)}


def install_hint(module: str | None, service: str | None = None) -> str:
    """``pip install 'riskfield[X]'`` for a missing optional module, the service's extra when
    the module is not in the table; empty when neither is known."""
    top = (module or "").split(".")[0]
    extra = EXTRAS.get(service or "") if service in EXTRAS else None
    extra = extra or MODULE_EXTRAS.get(top)
    return f"pip install 'riskfield[{extra}]'" if extra else ""


def missing_extra(exc: ModuleNotFoundError) -> str | None:
    """One line for a missing optional module (``exc.name`` in ``MODULE_EXTRAS``), else None
    (a missing module of riskfield itself, or an unknown one, stays a real error)."""
    top = (exc.name or "").split(".")[0]
    if top not in MODULE_EXTRAS:
        return None
    return f"this needs the Python package {top!r}: {install_hint(top)}"


@dataclass(frozen=True)
class ServiceSpec:
    name: str
    settings: type[NodeSettings]
    setup: Callable[[Node, Any], Any]


class ServiceUnavailable(RuntimeError):
    """A service that is unknown, or whose dependencies are not installed."""


def unknown_service(name: str) -> str:
    """The error for a service name nobody answers to: the nearest known name, then all of them."""
    close = difflib.get_close_matches(name, list(SERVICES), n=1, cutoff=0.6)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"unknown service {name!r}{hint} (known: {', '.join(SERVICES)})"


def load_service(name: str, runnable: bool = True) -> ServiceSpec:
    """The service's spec; ``runnable=False``: its settings are all that is wanted, so a package
    it needs only once it runs (``RUNTIME_NEEDS``: the viewer's rerun) may be missing."""
    target = SERVICES.get(name)
    if target is None:
        raise ServiceUnavailable(unknown_service(name))
    module, attr = target.split(":")
    try:
        spec = getattr(importlib.import_module(module), attr)
        for needed in RUNTIME_NEEDS.get(name, ()) if runnable else ():
            if importlib.util.find_spec(needed) is None:
                raise ModuleNotFoundError(f"No module named {needed!r}", name=needed)
    except ModuleNotFoundError as exc:
        if exc.name and not exc.name.startswith("riskfield"):
            raise needs_package(name, exc.name) from exc
        raise ServiceUnavailable(f"service {name!r} is not available in this build ({exc})") from exc
    return spec


def needs_package(service: str, module: str) -> ServiceUnavailable:
    """The one-line error of a service missing an optional package, with the install hint."""
    top = module.split(".")[0]
    hint = install_hint(top, service)
    return ServiceUnavailable(f"service {service!r} needs the Python package {top!r}{': ' + hint if hint else ''}")


def build_settings(spec: ServiceSpec, overrides: dict[str, Any] | None = None) -> NodeSettings:
    """Settings of a service from defaults, config file, environment and ``overrides``."""
    return spec.settings(**{k: v for k, v in (overrides or {}).items() if v is not None})


def run_service(name: str, overrides: dict[str, Any] | None = None, *, duration_s: float | None = None) -> int:
    """Start one service in this process and serve until a signal; the exit code.

    Start-up (imports, session, the service's setup: where kernels load or compile) is reported:
    a line when it begins, one every few seconds saying what it is doing while it lasts
    (``logs.StartupReport``), each kernel numba compiles (``jit.CompileWatch``), and the node's
    "up" line with the seconds since spawn."""
    log = setup_logging(name)
    with StartupReport(log, compiling=_compiling):
        spec = load_service(name)  # a missing extra: one line from the caller, nothing before it
        settings = build_settings(spec, overrides)
        setup_logging(name, settings.log_level)  # the level asked for, from the first line on
        log.info("%s starting (pid %d, %.1f s after spawn)", name, os.getpid(), process_age_s())
        compile_watch()  # registered before setup, where kernels load (or, on a cold cache, compile)
        # A stop asked for while the session is still opening (a router being dialled) is honoured
        # as soon as the node exists, with the same clean exit as later on.
        early = threading.Event()
        restore = catch_stop_signals(lambda _name: early.set())
        try:
            node = Node(spec.name, settings)
        finally:
            restore()
        try:
            handle = spec.setup(node, settings)
        except ModuleNotFoundError as exc:  # a package the setup needs (numba where it builds a kernel)
            node.close()
            if exc.name and not exc.name.startswith("riskfield"):
                raise needs_package(name, exc.name) from exc
            raise
        except BaseException:
            node.close()
            raise
    watch = compile_watch()  # numba may have been imported by setup only
    if watch is not None and watch.compiled:
        node.log.warning("compiled %d kernel signature(s) in %.1f s at start: numba's cache was cold or stale; "
                         "`riskfield warmup` (make setup) compiles them once, ahead of start", watch.compiled,
                         watch.seconds)
    if early.is_set():
        node.stop("signal during start-up")
    try:
        return node.run(duration_s)
    finally:
        close = getattr(handle, "close", None)
        if callable(close):
            close()


def _compiling() -> str:
    """What a start-up report says while numba compiles a kernel, else ``""``. Runs on the report's
    thread: reads the watch if there is one, never imports (numba may be half-imported right now)."""
    jit = sys.modules.get("riskfield.services.runtime.jit")
    watch = getattr(jit, "_WATCH", None)
    now = watch.current() if watch is not None else None
    if now is None:
        return ""
    return f"compiling kernel {now[0]} for {now[1]:.0f} s ({watch.compiled} compiled so far)"
