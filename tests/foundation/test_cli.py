"""The `riskfield` command line, run as users run it: a real process."""

from __future__ import annotations

import importlib.metadata
import json
import signal
import subprocess
import sys

from riskfield import __version__
from riskfield.testing import client_session, free_port, wait_alive

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


def test_bench_codec_writes_a_summary(tmp_path):
    r = _run("bench", "codec", "--repeat", "3", "--out", str(tmp_path), timeout=120)
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    row = summary["decode PerceptionFrame 512x384"]
    assert row["n"] == 3 and row["median_ms"] > 0  # measured; how fast is the bench's report, not a test
    assert any(k.startswith("zenoh round trip") for k in summary)
    assert _run("bench", "nope").returncode == 2
