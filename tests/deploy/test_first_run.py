"""A new user's first run: a fresh clone, no compiled kernels anywhere, passes `riskfield demo` the
first time, on a cold numba cache."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_a_fresh_clone_passes_the_demo_on_its_first_run():
    """``git clone`` of this checkout into a temporary folder, installed editable into a new venv,
    then ``riskfield demo``: it warms its kernels (cold: minutes), then runs both experiments.

    Fresh: the source tree, its install and numba's cache (NUMBA_CACHE_DIR unset,
    so numba caches in ``__pycache__`` beside the clone's sources, as for a new user). Reused: the
    third-party packages, through a ``.pth`` line naming this venv's site-packages (a path line only:
    this venv's own editable finder of riskfield is not loaded). Installing them again would test
    pip and its download cache, not the first run."""
    work = Path(tempfile.mkdtemp(prefix="rf-first-run-"))
    try:
        clone, venv, out = work / "clone", work / "venv", work / "out"
        subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True, timeout=300)
        assert not list(clone.rglob("*.nbi")), "a clone holds no compiled kernels"
        subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
        site = next((venv / "lib").glob("python3*/site-packages"))
        (site / "riskfield-deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
        python = venv / "bin" / "python"
        subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "-e", str(clone)], check=True,
                       timeout=900, capture_output=True)
        env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
        r = subprocess.run([str(python), "-m", "riskfield", "demo", "--out", str(out)], cwd=clone, env=env,
                           capture_output=True, text=True, timeout=2100)
        log = (out / "stack.log").read_text()[-4000:] if (out / "stack.log").is_file() else ""
        assert r.returncode == 0, r.stderr[-4000:] + log
        summary = json.loads((out / "summary.json").read_text())
        assert summary["experiments_completed"] is True and summary["services_ended_badly"] == [], summary
        assert "kernels_ready" in summary["phases_s"], summary["phases_s"]
        assert any(clone.rglob("*.nbi")), "the kernels were cached in the clone, where its nodes load them"
        # Warmed before the stack started: no node compiled a kernel, at start or later.
        assert "compiling kernel" not in (out / "stack.log").read_text()
    finally:
        shutil.rmtree(work, ignore_errors=True)  # the clone, its venv, its kernels and the demo's recording
