"""How a service declares itself, and the one function that runs any of them.

A service module exposes ``SERVICE = ServiceSpec(name, Settings, setup)``. ``setup(node,
settings)`` builds the pure core, declares subscriptions and timers on the node and may
return an object with ``close()`` (called after the loop ends).
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .node import Node
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
    "limo": "riskfield.edge.limo.node:SERVICE",
    "joystick": "riskfield.edge.joystick.node:SERVICE",
    "mavlink": "riskfield.edge.mavlink.node:SERVICE",
    "record": "riskfield.services.recorder.node:RECORD",
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
    "limo": "robot",
    "joystick": "robot",
    "mavlink": "robot",
    "record": "tools",
    "replay": "tools",
    "viewer": "viz",
    "ros2-bridge": "ros2",
}


@dataclass(frozen=True)
class ServiceSpec:
    name: str
    settings: type[NodeSettings]
    setup: Callable[[Node, Any], Any]


class ServiceUnavailable(RuntimeError):
    """A service that is unknown, or whose dependencies are not installed."""


def load_service(name: str) -> ServiceSpec:
    target = SERVICES.get(name)
    if target is None:
        raise ServiceUnavailable(f"unknown service {name!r}; known: {', '.join(SERVICES)}")
    module, attr = target.split(":")
    try:
        spec = getattr(importlib.import_module(module), attr)
    except ModuleNotFoundError as exc:
        if exc.name and not exc.name.startswith("riskfield"):
            extra = EXTRAS.get(name)
            hint = f": pip install 'riskfield[{extra}]'" if extra else ""
            raise ServiceUnavailable(f"service {name!r} needs the Python package {exc.name!r}{hint}") from exc
        raise ServiceUnavailable(f"service {name!r} is not available in this build ({exc})") from exc
    return spec


def build_settings(spec: ServiceSpec, overrides: dict[str, Any] | None = None) -> NodeSettings:
    """Settings of a service from defaults, config file, environment and ``overrides``."""
    return spec.settings(**{k: v for k, v in (overrides or {}).items() if v is not None})


def run_service(name: str, overrides: dict[str, Any] | None = None, *, duration_s: float | None = None) -> int:
    """Start one service in this process and serve until a signal; the exit code."""
    spec = load_service(name)
    settings = build_settings(spec, overrides)
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
    except BaseException:
        node.close()
        raise
    if early.is_set():
        node.stop("signal during start-up")
    try:
        return node.run(duration_s)
    finally:
        close = getattr(handle, "close", None)
        if callable(close):
            close()
