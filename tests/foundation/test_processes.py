"""The runtime's process runner (services/runtime/processes.py): real processes, a real router."""

from __future__ import annotations

import os
import signal
import sys
import threading

import pytest

from riskfield.protocol import Keys
from riskfield.services.runtime.processes import (
    NO_RESTART,
    Child,
    EmbeddedRouter,
    ProcessRunner,
    RestartPolicy,
    client_session,
    free_port,
    wait_alive,
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


# -- supervision -----------------------------------------------------------------------------------

#: a process that runs argv[1] seconds, then exits with code argv[2]
CRASHER = "import sys, time; time.sleep(float(sys.argv[1])); sys.exit(int(sys.argv[2]))"


def _crasher(runner: ProcessRunner, run_s: float, code: int) -> Child:
    child = Child("crasher", "crasher", [sys.executable, "-c", CRASHER, str(run_s), str(code)])
    runner.children["crasher"] = child
    return child


def test_restart_policy_backs_off_exponentially_within_its_bound():
    p = RestartPolicy(backoff_s=0.5, backoff_max_s=4.0)
    assert [p.delay(n) for n in range(1, 7)] == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    for bad in (dict(backoff_s=0.0), dict(backoff_s=5.0, backoff_max_s=1.0), dict(healthy_s=0.0),
                dict(max_restarts=-1)):
        with pytest.raises(ValueError, match="restart policy"):
            RestartPolicy(**bad)


def test_a_crashed_service_is_restarted_and_the_others_keep_running(tmp_path):
    """SIGKILL one service of a watched stack: it comes back (a new process, alive again on the
    network), the router is the same process throughout, one log line says so, and a stop asked
    for afterwards is clean (exit code 0: the crash was dealt with)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys(robot="t_runner_restart")
    log = tmp_path / "stack.log"
    runner = ProcessRunner(endpoint, keys, log_path=log, restart=RestartPolicy(backoff_s=0.2))
    runner.add("router", "router", ["--robot", keys.robot])
    runner.add("relay", "relay", ["--robot", keys.robot])
    code: list[int] = []
    watcher = threading.Thread(target=lambda: code.append(runner.watch(ready_timeout_s=None)), daemon=True)
    watcher.start()
    try:
        with client_session(endpoint, timeout_s=30) as session:
            assert runner.wait_ready(session, timeout_s=60), runner.children["relay"].output
            router_pid = runner.children["router"].proc.pid
            relay = runner.children["relay"]
            first = relay.proc.pid
            os.kill(first, signal.SIGKILL)
            assert wait_until(lambda: relay.restarts == 1 and relay.alive(), 30.0), log.read_text()
            assert relay.pids == [first, relay.proc.pid] and relay.proc.pid != first
            assert wait_alive(session, keys.alive("relay"), 30.0), relay.output
            assert runner.children["router"].proc.pid == router_pid and runner.children["router"].alive()
    finally:
        runner.request_stop()
        watcher.join(60)
    assert code == [0], log.read_text()
    lines = [line for line in log.read_text().splitlines() if "restarting in" in line]
    assert len(lines) == 1 and "relay exited with signal SIGKILL" in lines[0], lines
    assert relay.output.count("relay stopped") == 1  # the second incarnation stopped cleanly


def test_a_service_crashing_in_a_row_exhausts_its_restart_budget(tmp_path):
    log = tmp_path / "stack.log"
    policy = RestartPolicy(backoff_s=0.1, backoff_max_s=0.2, healthy_s=60.0, max_restarts=3)
    with ProcessRunner(f"tcp/127.0.0.1:{free_port()}", log_path=log, restart=policy) as runner:
        child = _crasher(runner, 0.0, 1)
        assert runner.watch(duration_s=120, ready_timeout_s=None) == 1  # returns on the budget, not the duration
    assert child.restarts == 3 and len(set(child.pids)) == 4
    text = log.read_text()
    assert all(f"restarting in {d}" in text for d in ("0.1 s (restart 1,", "0.2 s (restart 2,", "0.2 s (restart 3,"))
    assert "restart budget exhausted (3 restarts in a row)" in runner.failed


def test_a_healthy_run_resets_the_back_off_and_the_budget(tmp_path):
    policy = RestartPolicy(backoff_s=0.05, backoff_max_s=10.0, healthy_s=0.2, max_restarts=1)
    with ProcessRunner(f"tcp/127.0.0.1:{free_port()}", restart=policy) as runner:
        child = _crasher(runner, 0.3, 1)  # each run outlives healthy_s: every crash is the first in a row
        done = threading.Event()
        watcher = threading.Thread(target=lambda: (runner.watch(ready_timeout_s=None), done.set()), daemon=True)
        watcher.start()
        assert wait_until(lambda: child.restarts >= 3 or done.is_set(), 60.0)
        runner.request_stop()
        watcher.join(30)
    assert child.restarts >= 3 and runner.failed is None


@pytest.mark.parametrize("policy", [NO_RESTART, RestartPolicy()], ids=["no-restart", "restart"])
def test_fail_fast_without_restarts_and_a_configuration_error_is_never_restarted(policy):
    with ProcessRunner(f"tcp/127.0.0.1:{free_port()}", restart=policy) as runner:
        child = _crasher(runner, 0.0, 1 if policy is NO_RESTART else 2)
        assert runner.watch(duration_s=120, ready_timeout_s=None) == 1
    assert child.restarts == 0 and runner.failed.startswith("crasher exited with code")
