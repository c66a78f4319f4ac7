"""The `riskfield` command line, run as users run it: a real process."""

from __future__ import annotations

import importlib.metadata
import json
import os
import signal
import subprocess
import sys

import pytest

from riskfield import __version__
from riskfield.testing import StatusWatch, client_session, free_port, wait_alive

RF = [sys.executable, "-m", "riskfield"]


def _run(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([*RF, *args], capture_output=True, text=True, timeout=timeout)


def test_version_matches_the_installed_distribution():
    """What `--version` prints is the version pip installed (pyproject.toml), not only a constant."""
    r = _run("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"riskfield {importlib.metadata.version('riskfield')}"
    assert __version__ == importlib.metadata.version("riskfield")


def test_schema_export(tmp_path):
    r = _run("schema", str(tmp_path / "schemas"))
    assert r.returncode == 0, r.stderr
    files = sorted(p.name for p in (tmp_path / "schemas").iterdir())
    assert "EsdfGrid.schema.json" in files and "VelocityCommand.schema.json" in files
    js = json.loads((tmp_path / "schemas" / "SafetyStatus.schema.json").read_text())
    assert js["properties"]["schema"]["const"] == "SafetyStatus/1"


def test_run_unknown_service_and_bad_config_fail_clearly(tmp_path):
    r = _run("run", "teleporter")
    assert r.returncode == 2 and "unknown service 'teleporter'" in r.stderr
    r = _run("run", "relay", "--set", "schema_name=Nope/1", "--connect", f"tcp/127.0.0.1:{free_port()}",
             "--set", "connect_timeout_s=0.5")
    assert r.returncode in (2, 3)
    r = _run("run", "relay", "--config", str(tmp_path / "missing.yaml"))
    assert r.returncode == 2 and "does not exist" in r.stderr


def test_up_starts_and_stops_a_set_of_processes(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([*RF, "up", "relay", "--listen", endpoint, "--robot", "t_up"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        with client_session(endpoint, timeout_s=30) as session:
            assert wait_alive(session, "rf/t_up/alive/router", 30)
            assert wait_alive(session, "rf/t_up/alive/relay", 30)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert "router | " in out and "relay  | " in out  # prefixed logs
    assert "relay stopped" in out and "router stopped" in out


def test_up_exits_non_zero_when_a_service_dies():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # --duration is far beyond the subprocess timeout: returning at all means it did not wait for it.
    r = subprocess.run([*RF, "up", "relay", "--listen", endpoint, "--duration", "3600",
                        "--config", "/nonexistent/riskfield.yaml"], capture_output=True, text=True, timeout=90)
    assert r.returncode == 1
    assert "exited with code" in r.stderr + r.stdout


def _up_and_kill_relay(robot: str, *flags: str) -> tuple[subprocess.Popen, int, StatusWatch, object]:
    """``riskfield up relay`` with ``flags``; SIGKILL the relay (its pid from its NodeStatus)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([*RF, "up", "relay", "--listen", endpoint, "--robot", robot, *flags],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    session_cm = client_session(endpoint, timeout_s=30)
    session = session_cm.__enter__()
    status = StatusWatch(session, f"rf/{robot}/status/relay")
    pid = status.wait(lambda st: True, 30.0).pid
    os.kill(pid, signal.SIGKILL)
    return proc, pid, status, session_cm


def test_up_restarts_a_crashed_service_and_a_later_stop_is_clean():
    proc, pid, status, session_cm = _up_and_kill_relay("t_up_restart", "--backoff", "0.2")
    try:
        assert status.wait(lambda st: st.pid != pid, 60.0).pid != pid  # a new relay process serves
        assert proc.poll() is None
        status.close()
        session_cm.__exit__(None, None, None)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert out.count("restarting in 0.2 s") == 1 and "relay exited with signal SIGKILL" in out, out
    assert "router stopped" in out and out.count("relay stopped") == 1


def test_up_no_restart_is_fail_fast():
    proc, _, status, session_cm = _up_and_kill_relay("t_up_failfast", "--no-restart")
    try:
        out, _ = proc.communicate(timeout=60)  # returns by itself: the stack stopped
    finally:
        status.close()
        session_cm.__exit__(None, None, None)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1 and "relay exited with code -9; stopping the stack" in out, out
    assert "restarting" not in out


def test_bench_codec_writes_a_summary(tmp_path):
    r = _run("bench", "codec", "--repeat", "3", "--out", str(tmp_path), timeout=120)
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    row = summary["decode PerceptionFrame 512x384"]
    assert row["n"] == 3 and row["median"] > 0  # measured; how fast is the bench's report, not a test
    assert any(k.startswith("zenoh round trip") for k in summary)
    assert _run("bench", "nope").returncode == 2


# -- messages a new user reads --------------------------------------------------------------------

def _run_without(modules: tuple[str, ...], *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """The CLI in a process where ``modules`` cannot be imported, as on an install without
    their extra (``None`` in ``sys.modules`` makes ``import`` raise ModuleNotFoundError)."""
    code = ("import sys\n"
            f"for m in {list(modules)!r}: sys.modules[m] = None\n"
            "from riskfield.cli import app\n"
            f"app({list(args)!r}, prog_name='riskfield')\n")
    env = {**os.environ, "COLUMNS": "200"}  # Rich tables one row per line, as on a wide terminal
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env)


def test_services_lists_real_extras_with_hints_rich_does_not_swallow():
    r = _run_without(("rerun",), "services")
    assert r.returncode == 0, r.stderr
    rows = {ln.split("│")[1].strip(): ln for ln in r.stdout.splitlines() if ln.count("│") >= 3}
    assert "riskfield[mapping]" in rows["mapping"] and " ok " in rows["mapping"]  # the extra keeps its brackets
    assert " ok " not in rows["viewer"]  # not "ok" without rerun (the viewer would crash)
    assert "pip install 'riskfield[viz]'" in rows["viewer"]  # not "pip install 'riskfield'"


def test_run_viewer_without_rerun_is_one_line_not_a_traceback():
    r = _run_without(("rerun",), "run", "viewer", "--duration", "1")
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and r.stderr.strip().count("\n") == 0, r.stderr
    assert "pip install 'riskfield[viz]'" in r.stderr


def test_demo_without_mcap_is_one_install_line(tmp_path):
    r = _run_without(("mcap",), "demo", "--out", str(tmp_path / "demo"), "--budget", "1")
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and r.stderr.strip().count("\n") == 0, r.stderr
    assert "'mcap'" in r.stderr and "pip install 'riskfield[tools]'" in r.stderr


def test_record_without_mcap_keeps_the_brackets_of_its_hint():
    r = _run_without(("mcap",), "record", "--duration", "1")
    assert r.returncode == 2 and "pip install 'riskfield[tools]'" in r.stderr, r.stderr


def test_bench_without_its_extra_is_one_install_line():
    r = _run_without(("numba",), "bench", "filter")
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and "pip install 'riskfield[robot]'" in r.stderr, r.stderr


@pytest.mark.parametrize("service", ["perception", "simulator"])
def test_run_without_numba_is_one_install_line(service, router_endpoint):
    """The simulated camera path runs compiled kernels only: without numba the node stops in its
    setup, where the kernels are built, with the service's install hint."""
    r = _run_without(("numba",), "run", service, "--connect", router_endpoint, "--duration", "1", timeout=120)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1] == f"service {service!r} needs the Python package 'numba': " \
                                                "pip install 'riskfield[sim]'", r.stderr


def test_bench_name_help_shows_that_benchmarks_options():
    r = _run("bench", "safety", "--help")
    assert r.returncode == 0, r.stderr
    assert "riskfield bench safety" in r.stdout and "--trajectories" in r.stdout
    generic = _run("bench", "--help")
    assert generic.returncode == 0 and "--trajectories" not in generic.stdout and "codec" in generic.stdout


def test_run_service_help_lists_its_settings():
    r = _run("run", "viewer", "--help")
    assert r.returncode == 0, r.stderr
    out = " ".join(r.stdout.split())
    assert "--connect" in out  # the command's own options first
    for name in ("z_slice", "pointmap_stride", "camera_hfov_deg"):
        assert name in out
    assert "float" in out and "0.1" in out and "height of the ESDF slice" in out  # type, default, description
    assert "common to every node" in out and "connect_timeout_s" in out
    assert "z_slice" not in _run("run", "--help").stdout  # without a service: the generic help


def test_malformed_endpoints_fail_at_once_in_one_line():
    for endpoint, hint in (("foo", "<protocol>/<address>"), ("127.0.0.1:7447", "tcp/127.0.0.1:7447")):
        # the default connect_timeout_s is 30 s: a retry loop would overrun this timeout
        r = _run("run", "relay", "--connect", endpoint, timeout=20)
        assert r.returncode == 2, r.stderr
        assert hint in r.stderr and ".rs:" not in r.stderr and "Json5" not in r.stderr, r.stderr
        assert "waiting" not in r.stderr


def test_missing_router_is_said_once_with_a_countdown_and_no_rust_paths():
    r = _run("run", "relay", "--connect", f"tcp/127.0.0.1:{free_port()}", "--set", "connect_timeout_s=3", timeout=60)
    assert r.returncode == 3
    waiting = [ln for ln in r.stderr.splitlines() if "waiting for a Zenoh router" in ln]
    assert len(waiting) == 1 and "giving up in 3 s" in waiting[0], r.stderr
    assert "no Zenoh router at" in r.stderr and ".rs:" not in r.stderr and "cargo" not in r.stderr


@pytest.mark.slow
def test_examples_ship_in_the_sdist(tmp_path):
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    assert "graft examples" in (root / "MANIFEST.in").read_text().splitlines()
    pytest = __import__("pytest")
    pytest.importorskip("build")
    r = subprocess.run([sys.executable, "-m", "build", "--sdist", "-o", str(tmp_path), str(root)],
                       capture_output=True, text=True, timeout=600)
    if r.returncode != 0 and "Could not find a version" in r.stdout + r.stderr:
        pytest.skip("no package index for the isolated build environment")
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    import tarfile

    (sdist,) = tmp_path.glob("riskfield-*.tar.gz")
    with tarfile.open(sdist) as tar:
        names = tar.getnames()
    assert any(n.endswith("/examples/esdf_planner.py") for n in names)
    assert not any("__pycache__" in n for n in names)


def test_a_busy_listen_port_fails_at_once_without_rust_paths():
    from riskfield.testing import ZenohRouter

    with ZenohRouter() as router:  # holds the port
        r = _run("run", "router", "--listen", router.endpoint, timeout=20)  # no 30 s of retries
    assert r.returncode == 3, r.stderr
    assert f"cannot listen on {router.endpoint}" in r.stderr and "Address already in use" in r.stderr
    assert ".rs:" not in r.stderr and "waiting" not in r.stderr


def test_endpoint_check_and_zenoh_message_units():
    import pytest

    from riskfield.services.runtime.session import check_endpoint, zenoh_message

    for good in ("tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/robot-router:7447", "tcp/0.0.0.0:0",
                 "tls/host.local:7447?x=1#y", "unixsock-stream//tmp/zenoh.sock"):
        assert check_endpoint(good) == good
    for bad, words in (("foo", "<protocol>/<address>"), ("127.0.0.1:7447", "did you mean tcp/127.0.0.1:7447"),
                       ("tcp/127.0.0.1", "host:port"), ("tcp/127.0.0.1:70000", "65535"), ("tcp/:7447", "host:port")):
        with pytest.raises(ValueError, match=words):
            check_endpoint(bad)
    raw = ('Json5Err(Message { msg: "Endpoints must be of the form <protocol>/<address>: foo at '
           '/root/.cargo/git/checkouts/zenoh-x/commons/zenoh-protocol/src/core/endpoint.rs:615.", location: '
           'Some(Location { line: 1, column: 2 }) }) at /root/.cargo/git/checkouts/zenoh-x/zenoh/src/api/config.rs:86.')
    assert zenoh_message(raw) == "Endpoints must be of the form <protocol>/<address>: foo"
    assert zenoh_message("Unable to connect to any of [Single(tcp/127.0.0.1:1)]!  at /a/b/orchestrator.rs:447.") == (
        "Unable to connect to any of [Single(tcp/127.0.0.1:1)]")


def test_up_profiles_name_their_services_and_refuse_what_they_cannot_start():
    from riskfield.cli import UP_PROFILES

    assert UP_PROFILES["robot"] == ("camera", "limo", "joystick", "safety-filter")
    r = _run("up", "--profile", "moon", "--no-router", "--duration", "1")
    assert r.returncode == 2 and "unknown profile 'moon'" in r.stderr and "robot" in r.stderr, r.stderr
    r = _run("up", "relay", "--dry-run", "--no-router", "--duration", "1")
    assert r.returncode == 2 and "--dry-run is the LIMO bridge's" in r.stderr, r.stderr
    help_ = _run("up", "--help").stdout
    assert "--profile" in help_ and "--dry-run" in help_ and "--server" in help_
