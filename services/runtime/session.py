"""Zenoh session from node settings: mode, endpoints, scouting, TLS, user/password.

``endpoint_config`` is the one Zenoh config builder: nodes (``zenoh_config``), the test
helpers (``riskfield/testing.py``), the fault-drill agents and the codec bench all use it.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import logging
import re
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import zenoh

from .settings import NodeSettings

log = logging.getLogger("riskfield.session")

#: Zenoh's endpoint form, ``<protocol>/<address>[?<metadata>][#<config>]`` (upstream:
#: eclipse-zenoh/zenoh, commons/zenoh-protocol/src/core/endpoint.rs, ``EndPoint::try_from``).
_ENDPOINT = re.compile(r"^(?P<proto>[a-z][a-z0-9+.-]*)/(?P<address>[^?#]+)(\?[^#]*)?(#.*)?$")
#: Protocols whose address is ``host:port`` (IPv6 hosts in brackets).
_HOST_PORT = frozenset({"tcp", "udp", "tls", "quic", "ws"})
_HOST_PORT_ADDR = re.compile(r"^(?P<host>\[[0-9A-Fa-f:.%a-zA-Z]+\]|[A-Za-z0-9_.-]+):(?P<port>\d{1,5})$")
#: Rust source locations Zenoh appends to its errors (`` at /root/.cargo/.../config.rs:86.``).
_RUST_PATH = re.compile(r"\s+at\s+\S+\.rs:\d+(:\d+)?\.?")


def check_endpoint(endpoint: str) -> str:
    """``endpoint`` if it is a Zenoh endpoint, else a ValueError saying what form it needs,
    before anything is dialled."""
    example = "e.g. tcp/127.0.0.1:7447"
    m = _ENDPOINT.match(endpoint) if isinstance(endpoint, str) else None
    if m is None:
        if isinstance(endpoint, str) and _HOST_PORT_ADDR.match(endpoint):
            raise ValueError(f"endpoint {endpoint!r} has no protocol: did you mean tcp/{endpoint}?")
        raise ValueError(f"endpoint {endpoint!r} is not <protocol>/<address>, {example}")
    if m["proto"] in _HOST_PORT:
        a = _HOST_PORT_ADDR.match(m["address"])
        if a is None or int(a["port"]) > 65535:
            raise ValueError(f"endpoint {endpoint!r}: a {m['proto']} address is host:port with a port up to "
                             f"65535, {example}")
    return endpoint


#: ``--connect``'s help, the same for ``riskfield run`` (``riskfield.cli.Connect``) and the argparse tools.
CONNECT_HELP = "Zenoh endpoint to dial (repeatable, or comma-separated)."


def add_connect_argument(parser: argparse.ArgumentParser) -> None:
    """The one ``-e/--connect ENDPOINT`` of the tools built on argparse (the keyboard, the fault
    drill's agents), as zenoh-python's examples share ``add_config_arguments``. Not in the example
    planner: an external client, it depends on the wire contract only."""
    parser.add_argument("-e", "--connect", action="append", metavar="ENDPOINT", help=CONNECT_HELP)


def zenoh_message(exc: BaseException | str) -> str:
    """A Zenoh error as one readable line: Rust source paths and Json5 wrapping removed."""
    text = _RUST_PATH.sub("", str(exc))
    inner = re.search(r'msg: "(.*?)"(, location|\s*\})', text)
    if inner:
        text = inner.group(1)
    return " ".join(text.split()).rstrip(".!") or type(exc).__name__


def endpoint_config(mode: str = "client", connect: Sequence[str] = (), listen: Sequence[str] = (), *,
                    multicast_scouting: bool = False, base: Path | None = None,
                    extra: Mapping[str, object] | None = None) -> zenoh.Config:
    """A Zenoh config: mode, endpoints and scouting, on top of ``base`` (a JSON5 file) and
    followed by ``extra`` (config path → value). Multicast scouting stays off unless asked
    for: sessions connect to the endpoints they are given, which is what works across
    containers and in tests."""
    for e in (*connect, *listen):
        check_endpoint(e)
    cfg = zenoh.Config.from_file(str(base)) if base else zenoh.Config()
    if base is None:
        # Zenoh's default (zenoh-python 1.x: transport/shared_memory enabled with
        # transport_optimization, a 16 MiB pool per session for messages over 3 KB) makes every
        # same-host peer keep the pool of each session it ever talked to: a router or a mapper
        # grows ~20 MB per perception restart (tests/deploy/test_soak.py). Loopback
        # TCP carries our images well, and containers do not share /dev/shm anyway; a user's
        # own Zenoh config file decides for itself.
        cfg.insert_json5("transport/shared_memory/enabled", "false")
    cfg.insert_json5("mode", json.dumps(mode))
    connect = [e for e in connect if e not in listen]  # a router never dials itself
    if connect:
        cfg.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        cfg.insert_json5("listen/endpoints", json.dumps(list(listen)))
    cfg.insert_json5("scouting/multicast/enabled", json.dumps(multicast_scouting))
    for path, value in (extra or {}).items():
        cfg.insert_json5(path, json.dumps(value))
    return cfg


def zenoh_config(s: NodeSettings) -> zenoh.Config:
    """The Zenoh config of a node: ``endpoint_config`` plus TLS, user/password and the service's own
    paths (``NodeSettings.zenoh_extra``)."""
    cfg = endpoint_config(s.mode, s.connect, s.listen, multicast_scouting=s.multicast_scouting,
                          base=s.zenoh_config)

    def put(path: str, value: object) -> None:
        cfg.insert_json5(path, json.dumps(value))

    if s.tls_root_ca:
        put("transport/link/tls/root_ca_certificate", str(s.tls_root_ca))
    if s.tls_cert and s.tls_key:
        if s.listen:
            put("transport/link/tls/listen_certificate", str(s.tls_cert))
            put("transport/link/tls/listen_private_key", str(s.tls_key))
        put("transport/link/tls/connect_certificate", str(s.tls_cert))
        put("transport/link/tls/connect_private_key", str(s.tls_key))
    if s.tls_mtls:
        put("transport/link/tls/enable_mtls", True)
    password = s.password
    if password is None and s.password_file is not None:
        password = s.password_file.read_text().strip()
    if s.user is not None and password is not None:
        put("transport/auth/usrpwd/user", s.user)
        put("transport/auth/usrpwd/password", password)
    for path, value in s.zenoh_extra().items():
        put(path, value)
    return cfg


class InsecureListen(ValueError):
    """A node would listen beyond loopback without TLS and users, and ``insecure`` is not set."""


#: Protocols whose links are encrypted and authenticate the router (Zenoh's TLS and QUIC links).
_ENCRYPTED = frozenset({"tls", "quic"})


def loopback(host: str) -> bool:
    """Only this host reaches ``host`` (a loopback address or localhost; not a name or 0.0.0.0)."""
    host = host.strip("[]").split("%")[0]
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name or an interface: reachable from elsewhere


def only_this_host(host: str, published_on: str | None = None) -> bool:
    """A listener on ``host`` is reached from this host only: ``host`` is loopback, or (in a
    container) the host address its port is published on is."""
    return loopback(host) or (published_on is not None and loopback(published_on))


def exposed(cfg: zenoh.Config, published_on: str | None = None) -> list[str]:
    """The listen endpoints of ``cfg`` that others than this host reach without TLS and users: any
    host:port listener off loopback (``[::]`` and ``0.0.0.0`` included) unless it is a TLS/QUIC link
    and the config holds a user dictionary (``transport/auth/usrpwd/dictionary_file``). In a
    container, ``published_on`` is the host address its listeners are published on: they count as
    reachable from there (the container's own network holds only the project's containers)."""
    raw = json.loads(cfg.get_json("listen/endpoints"))
    mode = json.loads(cfg.get_json("mode"))
    # Zenoh's default is per mode ({"router": [...], "peer": [...]}; DEFAULT_CONFIG.json5 `listen`).
    endpoints = raw.get(mode, []) if isinstance(raw, dict) else raw
    users = json.loads(cfg.get_json("transport/auth/usrpwd/dictionary_file")) is not None
    out = []
    for e in endpoints:
        m = _ENDPOINT.match(e)
        if m is None or m["proto"] not in _HOST_PORT:
            continue  # unix sockets, serial lines: not on a network
        a = _HOST_PORT_ADDR.match(m["address"])
        if a is not None and only_this_host(a["host"], published_on):
            continue
        if m["proto"] in _ENCRYPTED and users:
            continue
        out.append(e)
    return out


def check_exposure(cfg: zenoh.Config, s: NodeSettings) -> None:
    """Refuse (or, with ``insecure``, warn about) listening beyond loopback in the clear."""
    bare = exposed(cfg, s.published_on)
    if not bare:
        return
    what = ", ".join(bare) + ("" if s.published_on is None else f" (published on {s.published_on})")
    if not s.insecure:
        raise InsecureListen(
            f"refusing to listen on {what} without TLS and users: anyone on that network could put "
            "cmd/safe. Listen on tcp/127.0.0.1:PORT, or use tls/ endpoints with a user dictionary "
            "(deploy/zenoh/router-secure.json5, `riskfield secrets`), or set insecure=true to accept it")
    log.warning("INSECURE: listening on %s without TLS and users (insecure=true): anyone who reaches it "
                "may put any key, cmd/safe included", what)


def open_session(s: NodeSettings) -> zenoh.Session:
    """Open a session, retrying while the router is not up yet (up to ``connect_timeout_s``).

    The wait is said once, then counted down every ``_COUNTDOWN_S``; a config Zenoh rejects
    (not a missing router) fails at once. A node that would listen beyond loopback without TLS
    and users does not start (``check_exposure``)."""
    cfg = zenoh_config(s)  # endpoint syntax is checked here, before anything is dialled
    check_exposure(cfg, s)
    deadline = time.monotonic() + s.connect_timeout_s
    delay = 0.05
    said_at: float | None = None
    while True:
        try:
            return zenoh.open(cfg)
        except zenoh.ZError as exc:
            now = time.monotonic()
            if s.listen and "listener" in str(exc):  # our own port (busy, bad address): no router will fix it
                raise ConnectionError(f"cannot listen on {', '.join(s.listen)}: {zenoh_message(exc)}") from exc
            where = ", ".join(s.connect) or "(no endpoint)"
            if now + delay > deadline:
                raise ConnectionError(f"no Zenoh router at {where} after {s.connect_timeout_s:g} s "
                                      f"({s.mode}): {zenoh_message(exc)}") from exc
            if said_at is None:
                log.info("waiting for a Zenoh router at %s (giving up in %.0f s)", where, deadline - now)
                said_at = now
            elif now - said_at >= _COUNTDOWN_S:
                log.info("still no router at %s, %.0f s left", where, deadline - now)
                said_at = now
            time.sleep(delay)
            delay = min(delay * 2, 1.0)
            cfg = zenoh_config(s)  # a Config is consumed by zenoh.open


_COUNTDOWN_S = 10.0
