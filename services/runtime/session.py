"""Zenoh session from node settings: mode, endpoints, scouting, TLS, user/password.

``endpoint_config`` is the one Zenoh config builder: nodes (``zenoh_config``), the test
helpers (``riskfield.testing``), the fault-drill agents and the codec bench all use it.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import zenoh

from .settings import NodeSettings

log = logging.getLogger("riskfield.session")


def endpoint_config(mode: str = "client", connect: Sequence[str] = (), listen: Sequence[str] = (), *,
                    multicast_scouting: bool = False, base: Path | None = None,
                    extra: Mapping[str, object] | None = None) -> zenoh.Config:
    """A Zenoh config: mode, endpoints and scouting, on top of ``base`` (a JSON5 file) and
    followed by ``extra`` (config path → value). Multicast scouting stays off unless asked
    for: sessions connect to the endpoints they are given, which is what works across
    containers and in tests."""
    cfg = zenoh.Config.from_file(str(base)) if base else zenoh.Config()
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
    """The Zenoh config of a node: ``endpoint_config`` plus TLS and user/password."""
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
    return cfg


def open_session(s: NodeSettings) -> zenoh.Session:
    """Open a session, retrying while the router is not up yet (up to ``connect_timeout_s``)."""
    deadline = time.monotonic() + s.connect_timeout_s
    delay = 0.05
    while True:
        try:
            return zenoh.open(zenoh_config(s))
        except zenoh.ZError as exc:
            if time.monotonic() + delay > deadline:
                raise ConnectionError(f"could not open a Zenoh session ({s.mode} → {s.connect}): {exc}") from exc
            log.info("waiting for a Zenoh router at %s (%s)", ", ".join(s.connect), exc)
            time.sleep(delay)
            delay = min(delay * 2, 1.0)
