"""Runtime pieces without a network: settings precedence, inbox queues, log rate limiting."""

from __future__ import annotations

import logging
import threading
from typing import ClassVar

import pytest

from riskfield.protocol import Limits
from riskfield.services.runtime import Inbox, NodeSettings, RateLimitedLog, parse_overrides, zenoh_config
from riskfield.services.runtime.node import KEYED_SLOTS, _Sub


class DemoSettings(NodeSettings):
    SERVICE: ClassVar[str] = "demo-svc"
    rate_hz: float = 50.0
    name: str = "default"


@pytest.fixture
def clean_env(monkeypatch):
    for var in ("RISKFIELD_CONFIG", "RISKFIELD_CONNECT", "RISKFIELD_ROBOT", "RISKFIELD_RATE_HZ", "RISKFIELD_MODE",
                "RISKFIELD_LISTEN", "RISKFIELD_PREFIX", "RISKFIELD_NAME"):
        monkeypatch.delenv(var, raising=False)
    return monkeypatch


@pytest.fixture
def other_services():
    """What ``riskfield run`` tells the runtime: the other services' keys (mapping's section below)."""
    from riskfield.cli import every_service_settings
    from riskfield.services.runtime.settings import know_other_services

    know_other_services(every_service_settings)
    yield
    know_other_services(None)


def test_defaults(clean_env):
    s = DemoSettings()
    assert s.connect == ["tcp/127.0.0.1:7447"] and s.mode == "client" and s.robot == "limo1" and s.prefix == "rf"
    assert s.rate_hz == 50.0 and not s.multicast_scouting


@pytest.mark.parametrize("suffix", [".yaml", ".toml"])
def test_precedence_defaults_file_env_cli(clean_env, other_services, tmp_path, suffix):
    path = tmp_path / f"cfg{suffix}"
    if suffix == ".yaml":
        path.write_text("robot: fromfile\nname: fromfile\nrate_hz: 10\n"
                        "demo-svc:\n  rate_hz: 20\nmapping:\n  rate_hz: 99\n")
    else:
        path.write_text('robot = "fromfile"\nname = "fromfile"\nrate_hz = 10\n[demo_svc]\nrate_hz = 20\n')
    clean_env.setenv("RISKFIELD_CONFIG", str(path))
    s = DemoSettings()
    assert (s.robot, s.name, s.rate_hz) == ("fromfile", "fromfile", 20.0)  # service section beats top level
    clean_env.setenv("RISKFIELD_ROBOT", "fromenv")
    clean_env.setenv("RISKFIELD_CONNECT", "tcp/127.0.0.1:1, tcp/127.0.0.1:2")
    s = DemoSettings()
    assert s.robot == "fromenv" and s.name == "fromfile"
    assert s.connect == ["tcp/127.0.0.1:1", "tcp/127.0.0.1:2"]
    s = DemoSettings(**parse_overrides(["robot=fromcli", "rate_hz=33"]))
    assert (s.robot, s.rate_hz, s.name) == ("fromcli", 33.0, "fromfile")


def test_bad_config_is_a_clear_error(clean_env, tmp_path):
    bad = tmp_path / "cfg.ini"
    bad.write_text("x=1")
    with pytest.raises(ValueError, match=r"use \.yaml"):
        DemoSettings(config=bad)
    with pytest.raises(FileNotFoundError):
        DemoSettings(config=tmp_path / "missing.yaml")
    with pytest.raises(ValueError):
        DemoSettings(rate_hz="fast")
    with pytest.raises(ValueError, match="key=value"):
        parse_overrides(["novalue"])


def test_overrides_parse_yaml_values():
    assert parse_overrides(["a=1", "b.c=[1, 2]", "d=true", "e=text", "f-g=0.5"]) == {
        "a": 1, "b": {"c": [1, 2]}, "d": True, "e": "text", "f_g": 0.5}


def test_zenoh_config_has_no_multicast_and_no_self_dial(clean_env):
    s = DemoSettings(mode="router", listen=["tcp/127.0.0.1:9"], connect=["tcp/127.0.0.1:9", "tcp/127.0.0.1:10"])
    cfg = zenoh_config(s)
    assert cfg.get_json("scouting/multicast/enabled") == "false"
    connect = cfg.get_json("connect/endpoints")
    assert "127.0.0.1:10" in connect and "127.0.0.1:9" not in connect
    s = DemoSettings(user="op", password="pw", tls_root_ca="/ca.pem", tls_cert="/c.pem", tls_key="/k.pem",
                     tls_mtls=True)
    cfg = zenoh_config(s)
    assert cfg.get_json("transport/auth/usrpwd/user") == '"op"'
    assert cfg.get_json("transport/link/tls/connect_certificate") == '"/c.pem"'
    assert cfg.get_json("transport/link/tls/enable_mtls") == "true"


def test_shared_memory_is_off_unless_a_zenoh_config_file_decides(clean_env, tmp_path):
    from riskfield.services.runtime import endpoint_config

    shm = "transport/shared_memory/enabled"
    assert endpoint_config("client", ["tcp/127.0.0.1:9"]).get_json(shm) == "false"
    own = tmp_path / "zenoh.json5"
    own.write_text("{transport: {shared_memory: {enabled: true}}}")
    assert endpoint_config("client", ["tcp/127.0.0.1:9"], base=own).get_json(shm) == "true"


def test_latest_slot_keeps_only_the_newest():
    inbox = Inbox()
    slot = inbox.slot("s", "latest")
    for i in range(5):
        inbox.put(slot, i)
    assert inbox.get(0) == (slot, 4)
    assert inbox.get(0) is None
    assert slot.received == 5 and slot.dropped == 4


def test_fifo_slot_keeps_order_and_counts_overflow():
    inbox = Inbox()
    slot = inbox.slot("f", "fifo", maxlen=3)
    for i in range(5):
        inbox.put(slot, i)
    assert [inbox.get(0)[1] for _ in range(3)] == [2, 3, 4]
    assert slot.dropped == 2


def test_slots_are_served_round_robin():
    inbox = Inbox()
    a, b = inbox.slot("a", "fifo"), inbox.slot("b", "fifo")
    for i in range(3):
        inbox.put(a, f"a{i}")
    inbox.put(b, "b0")
    order = [inbox.get(0)[1] for _ in range(4)]
    assert order.index("b0") == 1


def test_a_wildcard_latest_subscription_keeps_the_newest_of_each_key_up_to_a_bound():
    """cmd/ref/<source>: a flood on one source's key never displaces another's newest value; keys
    past KEYED_SLOTS share one slot, so made-up keys cannot grow the inbox."""
    inbox = Inbox()
    sub = _Sub("rf/r/cmd/ref/**", inbox.slot("rf/r/cmd/ref/**", "latest"), None, print, Limits(),
               keyed=lambda k: inbox.slot(k, "latest"))
    inbox.put(sub.slot_for("rf/r/cmd/ref/joystick"), "joy")
    for i in range(50):
        inbox.put(sub.slot_for("rf/r/cmd/ref/navigator"), f"nav{i}")
    for i in range(KEYED_SLOTS + 5):
        inbox.put(sub.slot_for(f"rf/r/cmd/ref/made-up{i}"), f"x{i}")
    assert len(sub.slots) == 1 + KEYED_SLOTS
    got = []
    while (item := inbox.get(0)) is not None:
        assert item[0].owner is sub
        got.append(item[1])
    assert got[:2] == ["joy", "nav49"] and f"x{KEYED_SLOTS + 4}" in got
    assert sum(s.received for s in sub.slots) == 1 + 50 + KEYED_SLOTS + 5


def test_get_wakes_when_an_item_arrives():
    inbox = Inbox()
    slot = inbox.slot("s", "latest")
    threading.Timer(0.05, inbox.put, args=(slot, "x")).start()
    assert inbox.get(5.0) == (slot, "x")


def test_rate_limited_log_suppresses_and_counts(caplog):
    log = RateLimitedLog(logging.getLogger("rl"), period_s=60)
    with caplog.at_level(logging.WARNING):
        results = [log(logging.WARNING, "topic", f"bad {i}") for i in range(100)]
        log(logging.WARNING, "other", "different topic")
    assert results.count(True) == 1
    assert len(caplog.records) == 2
    log._last["topic"] -= 120
    with caplog.at_level(logging.WARNING):
        log(logging.WARNING, "topic", "again")
    assert "99 more like it suppressed" in caplog.records[-1].getMessage()


def _old_builder(mode: str, connect: list[str], listen: list[str]):
    """What testing.client_config / ZenohRouter / the fault agents / the codec bench each built by hand."""
    import json

    import zenoh

    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    if connect:
        cfg.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return cfg


@pytest.mark.parametrize(("mode", "connect", "listen"), [
    ("client", ["tcp/127.0.0.1:7001"], []),  # client_config, agents, bench_codec's echo process
    ("peer", ["tcp/127.0.0.1:7002"], []),  # client_config(mode="peer")
    ("router", [], ["tcp/127.0.0.1:7003"]),  # ZenohRouter
])
def test_the_one_config_builder_matches_the_hand_built_ones(clean_env, mode, connect, listen):
    from riskfield.services.runtime import endpoint_config
    from riskfield.testing import client_config

    new, old = endpoint_config(mode, connect, listen), _old_builder(mode, connect, listen)
    for path in ("mode", "connect/endpoints", "listen/endpoints", "scouting/multicast/enabled"):
        assert new.get_json(path) == old.get_json(path), path
    if mode != "router":
        assert client_config(connect[0], mode).get_json("connect/endpoints") == old.get_json("connect/endpoints")
    node = zenoh_config(DemoSettings(mode=mode, connect=connect, listen=listen))
    for path in ("mode", "connect/endpoints", "listen/endpoints", "scouting/multicast/enabled"):
        assert node.get_json(path) == old.get_json(path), path
    agent = endpoint_config("client", ["tcp/127.0.0.1:7004"],
                            extra={"connect/timeout_ms": -1, "connect/exit_on_failure": False})
    assert agent.get_json("connect/timeout_ms") == "-1" and agent.get_json("connect/exit_on_failure") == "false"


def test_stop_signals_reach_the_handler_and_are_restored():
    import os
    import signal

    from riskfield.services.runtime.signals import catch_stop_signals

    before = signal.getsignal(signal.SIGTERM)
    got: list[str] = []
    restore = catch_stop_signals(got.append)
    try:
        os.kill(os.getpid(), signal.SIGTERM)
    finally:
        restore()
    assert got == ["SIGTERM"] and signal.getsignal(signal.SIGTERM) is before
