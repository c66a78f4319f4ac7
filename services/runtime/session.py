"""Zenoh session from node settings: mode, endpoints, scouting, TLS, user/password."""

from __future__ import annotations

import json
import logging
import time

import zenoh

from .settings import NodeSettings

log = logging.getLogger("riskfield.session")


def zenoh_config(s: NodeSettings) -> zenoh.Config:
    """Build the Zenoh config. Multicast scouting stays off unless asked for: nodes connect
    to the endpoints they are given, which is what works across containers and in tests."""
    cfg = zenoh.Config.from_file(str(s.zenoh_config)) if s.zenoh_config else zenoh.Config()

    def put(path: str, value: object) -> None:
        cfg.insert_json5(path, json.dumps(value))

    put("mode", s.mode)
    connect = [e for e in s.connect if e not in s.listen]  # a router never dials itself
    if connect:
        put("connect/endpoints", connect)
    if s.listen:
        put("listen/endpoints", s.listen)
    put("scouting/multicast/enabled", s.multicast_scouting)
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
