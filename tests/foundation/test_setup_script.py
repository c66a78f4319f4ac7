"""scripts/setup.sh on a fresh machine: what each command installs, and that it says so.

The machine is a sandbox: a copy of the script with ``dpkg``, ``apt-get``, ``sudo`` and the
Python on ``PATH`` replaced by recorders (installing system packages and every extra for real
takes minutes and root; the script's decisions are what is checked here). The recorders log
their arguments and act as the real ones would for the script (dpkg knows the packages given as
installed, ``python3 -m venv`` makes a ``.venv`` whose python and riskfield log too)."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

RECORDER = """#!/usr/bin/env bash
echo "{name} $*" >> "$LOG"
{body}
"""
DPKG = 'for p in $INSTALLED; do [ "$2" = "$p" ] && exit 0; done; exit 1'
PYTHON = """if [ "$1" = -c ]; then echo /usr; exit 0; fi
if [ "$1 $2" = "-m venv" ]; then
  mkdir -p "$3/bin"
  printf '#!/usr/bin/env bash\\necho "venv-python $*" >> "$LOG"\\n' > "$3/bin/python"
  printf '#!/usr/bin/env bash\\necho "riskfield $*" >> "$LOG"\\n' > "$3/bin/riskfield"
  chmod +x "$3/bin/python" "$3/bin/riskfield"
fi"""


def _tool(folder: Path, name: str, body: str = "") -> None:
    path = folder / name
    path.write_text(RECORDER.format(name=name, body=body))
    path.chmod(path.stat().st_mode | stat.S_IEXEC)


@pytest.fixture
def machine(tmp_path):
    """A checkout (the script, pyproject.toml, setup.py) and a PATH of recorders."""
    repo, bin_ = tmp_path / "repo", tmp_path / "bin"
    (repo / "scripts").mkdir(parents=True)
    bin_.mkdir()
    for name in ("scripts/setup.sh", "pyproject.toml", "setup.py"):
        shutil.copy(ROOT / name, repo / name)
    _tool(bin_, "dpkg", DPKG)
    _tool(bin_, "apt-get")
    _tool(bin_, "sudo", '"$@"')
    _tool(bin_, "python3", PYTHON)
    _tool(bin_, "id", 'echo 0')
    return repo, bin_, tmp_path / "calls.log"


def _setup(machine, *args: str, installed: str = "") -> tuple[subprocess.CompletedProcess, list[str]]:
    repo, bin_, log = machine
    log.write_text("")
    env = {"PATH": f"{bin_}:/usr/bin:/bin", "LOG": str(log), "INSTALLED": installed, "HOME": str(repo)}
    r = subprocess.run(["bash", str(repo / "scripts" / "setup.sh"), *args], cwd=repo, env=env,
                       capture_output=True, text=True, timeout=60)
    return r, [c for c in log.read_text().splitlines() if not c.startswith("dpkg ")]  # the queries


#: What every run ends with, also when everything else is done (each a second or two then).
DONE = ["venv-python -m compileall -q protocol services edge riskfield", "riskfield warmup"]


def _apt_installed(calls: list[str]) -> set[str]:
    return {p for c in calls if c.startswith("apt-get ") and " install " in c for p in c.split()
            if not p.startswith("-") and p not in ("apt-get", "install")}


def test_demo_installs_what_the_demo_runs_and_no_docker_tooling(machine):
    r, calls = _setup(machine, "demo")
    assert r.returncode == 0, r.stderr
    assert _apt_installed(calls) == {"libgomp1", "libusb-1.0-0", "libgl1", "python3-venv"}
    pip = [c for c in calls if c.startswith("venv-python -m pip install") and "-e" in c]
    assert pip == ['venv-python -m pip install --progress-bar on -e .[all]']


def test_test_installs_everything_the_tests_use(machine):
    r, calls = _setup(machine, "test")
    assert r.returncode == 0, r.stderr
    assert {"docker-compose", "iproute2", "openssl", "python3-venv", "libgomp1"} <= _apt_installed(calls)
    assert 'venv-python -m pip install --progress-bar on -e .[all,dev]' in calls
    assert calls[-2:] == DONE
    everything = "libgomp1 libusb-1.0-0 libgl1 iproute2 openssl docker-compose"
    assert _setup(machine, installed=everything)[1] == DONE  # no argument: `test`, done


def test_every_step_says_what_it_does_and_pip_is_not_silenced(machine):
    r, calls = _setup(machine, "demo")
    steps = [line for line in r.stdout.splitlines() if line.startswith("setup (demo): [")]
    assert [s.split("]")[0][-3:] for s in steps] == ["1/4", "2/4", "3/4", "4/4"]
    pip = [c.split() for c in calls if c.startswith("venv-python -m pip")]
    assert pip and all("-q" not in c and "--quiet" not in c and "--progress-bar" in c for c in pip)
    assert all("-qq" not in c.split() for c in calls if c.startswith("apt-get"))  # -q: one line a package


def test_a_venv_that_exists_needs_no_python3_venv_and_a_demo_after_test_reinstalls_nothing(machine):
    _setup(machine, "test")
    r, calls = _setup(machine, "demo", installed="libgomp1 libusb-1.0-0 libgl1")
    assert r.returncode == 0, r.stderr
    assert _apt_installed(calls) == set() and calls == DONE


def test_an_unknown_command_is_refused(machine):
    r, _ = _setup(machine, "demoo")
    assert r.returncode == 2 and "usage: scripts/setup.sh [test|demo]" in r.stderr


def test_the_makefile_sets_up_per_command():
    text = (ROOT / "Makefile").read_text()
    assert "demo: setup-demo" in text and "bash scripts/setup.sh demo" in text
    assert "test: setup\n" in text and "bash scripts/setup.sh test" in text


def test_the_real_script_parses():
    assert subprocess.run(["bash", "-n", str(ROOT / "scripts" / "setup.sh")], timeout=30).returncode == 0
    assert os.access(ROOT / "scripts" / "setup.sh", os.R_OK)
