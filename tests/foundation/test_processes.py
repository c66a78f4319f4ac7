"""The runtime's process runner (services/runtime/processes.py): real processes, a real router."""

from __future__ import annotations

import signal
import sys

import pytest

from riskfield.protocol import Keys
from riskfield.services.runtime.processes import (
    Child,
    EmbeddedRouter,
    ProcessRunner,
    client_session,
    free_port,
    wait_until,
)
from riskfield.testing import ServiceProcess

#: a process that says it is ready, then ignores the signals named in argv[1:]
STUBBORN = """
import signal, sys, time
for name in sys.argv[1:]:
    signal.signal(getattr(signal, name), signal.SIG_IGN)
print("ready", flush=True)
time.sleep(120)
"""


def _stubborn(*ignored: str) -> Child:
    child = Child("stubborn", "stubborn", [sys.executable, "-c", STUBBORN, *ignored]).start()
    assert wait_until(lambda: "ready" in child.output, 30.0), child.output
    return child


def test_runner_starts_a_router_and_a_service_and_stops_them_cleanly(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    log = tmp_path / "stack.log"
    keys = Keys(robot="t_runner")
    with ProcessRunner(endpoint, keys, log_path=log) as runner:
        runner.add("router", "router", ["--robot", keys.robot])
        runner.add("relay", "relay", ["--robot", keys.robot])
        runner.start()
        with client_session(endpoint, timeout_s=30) as session:
            assert runner.wait_ready(session, timeout_s=60), runner.children["relay"].output
            assert runner.ready(session) == {"router", "relay"}
        assert runner.stop("relay") == 0  # one child alone: a clean SIGINT stop
        assert runner.children["router"].alive()
    assert runner.ended_badly() == [] and runner.children["router"].returncode == 0
    text = log.read_text()
    assert "router | " in text and "relay  | " in text  # prefixed by label, aligned
    assert "relay stopped" in runner.children["relay"].output


def test_wait_ready_is_false_once_a_child_has_exited():
    robot = "t_runner_dead"
    with EmbeddedRouter() as router, client_session(router.endpoint) as session, \
            ProcessRunner(router.endpoint, Keys(robot=robot)) as runner:
        runner.add("relay", "relay", ["--robot", robot, "--config", "/nonexistent/riskfield.yaml"])
        runner.start()
        assert not runner.wait_ready(session, timeout_s=120)  # returns on the exit, not the timeout
        assert runner.children["relay"].returncode == 2  # the CLI's code for a bad configuration
    assert runner.ended_badly() == ["relay"]
    assert "does not exist" in runner.children["relay"].output


def test_stop_escalates_to_sigterm_then_sigkill():
    child = _stubborn("SIGINT")
    code, escalated = child.stop(signal.SIGINT, timeout_s=0.5, term_s=10.0)
    assert (code, escalated) == (-signal.SIGTERM, "SIGTERM")
    child = _stubborn("SIGINT", "SIGTERM")
    code, escalated = child.stop(signal.SIGINT, timeout_s=0.5, term_s=0.5)
    assert (code, escalated) == (-signal.SIGKILL, "SIGKILL")


def test_a_clean_stop_needs_no_escalation():
    child = _stubborn()
    assert child.stop(signal.SIGTERM, timeout_s=10.0) == (-signal.SIGTERM, "")


def test_service_process_fails_a_test_when_the_service_ignores_the_signal():
    sp = ServiceProcess("relay", f"tcp/127.0.0.1:{free_port()}")
    sp._child = _stubborn("SIGINT")  # the same runner child, made deaf to SIGINT
    with pytest.raises(RuntimeError, match="ignored signal"):
        sp.stop(timeout_s=0.5)
    assert not sp.alive()
