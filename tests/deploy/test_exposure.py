"""Secure by default: a node that would listen beyond loopback without TLS and users does not
start, unless ``insecure`` says so (and it warns). Nothing here listens off loopback: the refused
endpoints are never opened, and the one the CLI is given is a documentation address (TEST-NET-1,
RFC 5737) that no interface here holds."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import pytest

from riskfield.services.runtime.session import InsecureListen, check_exposure, exposed, zenoh_config
from riskfield.services.runtime.settings import NodeSettings

REPO = Path(__file__).resolve().parents[2]
SECURE = REPO / "deploy" / "zenoh" / "router-secure.json5"


def _exposed(**kw) -> list[str]:
    s = NodeSettings(connect=[], **kw)
    return exposed(zenoh_config(s), s.published_on)


@pytest.mark.parametrize("listen", ["tcp/127.0.0.1:7447", "tcp/127.0.0.2:7447", "tcp/localhost:7447",
                                    "tcp/[::1]:7447", "udp/127.0.0.1:7447", "unixsock-stream//tmp/rf.sock"])
def test_loopback_listeners_are_not_exposed(listen: str) -> None:
    assert _exposed(mode="router", listen=[listen]) == []


@pytest.mark.parametrize("listen", ["tcp/0.0.0.0:7447", "tcp/[::]:7447", "tcp/192.168.1.5:7447", "udp/[::]:7447",
                                    "ws/0.0.0.0:8080", "tcp/robot-router:7447", "tls/[::]:7447"])
def test_listeners_beyond_loopback_in_the_clear_are_exposed(listen: str) -> None:
    # tls/ without a user dictionary counts too: anyone with a certificate, or none without mTLS.
    assert _exposed(mode="router", listen=[listen]) == [listen]


def test_tls_with_users_is_not_exposed_and_plain_tcp_beside_it_is() -> None:
    assert _exposed(mode="router", listen=["tls/[::]:7447"], zenoh_config=SECURE) == []
    assert _exposed(mode="router", listen=["tls/[::]:7447", "tcp/[::]:7448"], zenoh_config=SECURE) == ["tcp/[::]:7448"]


def test_a_peer_with_zenohs_default_listener_is_exposed() -> None:
    """A peer given no listen endpoint gets Zenoh's default for its mode (DEFAULT_CONFIG.json5
    `listen`: tcp/[::]:0, every interface)."""
    assert _exposed(mode="peer") == ["tcp/[::]:0"]
    assert _exposed(mode="client") == []


def test_a_container_is_judged_by_where_its_port_is_published() -> None:
    assert _exposed(mode="router", listen=["tcp/[::]:7447"], published_on="127.0.0.1") == []
    assert _exposed(mode="router", listen=["tcp/[::]:7447"], published_on="0.0.0.0") == ["tcp/[::]:7447"]


def test_insecure_starts_with_a_warning_and_without_it_the_node_refuses(caplog: pytest.LogCaptureFixture) -> None:
    s = NodeSettings(mode="router", connect=[], listen=["tcp/0.0.0.0:7447"])
    with pytest.raises(InsecureListen, match=r"tcp/0\.0\.0\.0:7447 without TLS and users.*insecure=true"):
        check_exposure(zenoh_config(s), s)
    loud = s.model_copy(update={"insecure": True})
    with caplog.at_level(logging.WARNING, logger="riskfield.session"):
        check_exposure(zenoh_config(loud), loud)
    assert [r.levelno for r in caplog.records] == [logging.WARNING]
    assert "INSECURE" in caplog.text and "cmd/safe" in caplog.text


def test_riskfield_run_router_refuses_to_listen_on_the_network_in_the_clear() -> None:
    """The CLI's own path: exit code 2 (a configuration error) with the reason, before anything listens."""
    proc = subprocess.run([sys.executable, "-m", "riskfield", "run", "router", "--listen", "tcp/192.0.2.1:7447",
                           "--duration", "1"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    out = " ".join((proc.stdout + proc.stderr).split())
    assert "refusing to listen on tcp/192.0.2.1:7447 without TLS and users" in out
    assert "insecure=true" in out
