"""benchmarks/RESULTS.md is made only of runs: riskfield/experiments/results.py assembles the stamped run
folders that benchmarks/regenerate.sh writes, keeps stamped sections and other writers' marked blocks,
and says so where a section has never been measured."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from riskfield.experiments import results as R

REPO = Path(__file__).resolve().parents[2]


def _run(out: Path, name: str, tables: str | None = "# its title\n\n| a | b |\n|---|---|\n| 1 | 2 |\n",
         summary: dict | None = None, commit: str = "abc1234", exit_code: int = 0) -> Path:
    run = out / name
    run.mkdir(parents=True)
    if tables is not None:
        (run / "tables.md").write_text(tables)
    if summary is not None:
        (run / "summary.json").write_text(json.dumps(summary))
    (run / "stamp.json").write_text(json.dumps({"command": f"riskfield bench x --out {run}", "commit": commit,
                                                "date": "2026-12-04 10:00 UTC", "wall_s": 71, "exit": exit_code}))
    return run


def test_sections_are_runs_with_their_stamps_and_nothing_else(tmp_path: Path) -> None:
    _run(tmp_path, "safety_riskfield_gt")
    _run(tmp_path, "filter", tables=None, summary={"results": {"m/after": {"step_us": {
        "n": 3, "median": 9.5, "p99": 11.25, "max": 12.0}}}, "ratios": {"a": {"x": 1.0, "y": 2.0},
                                                                       "b": {"x": 3.0, "y": 4.0}}})
    doc = R.assemble(tmp_path)
    gt = doc.split("## `riskfield bench safety --protocol riskfield --perception gt`")[1].split("\n## ")[0]
    assert "*Measured at commit `abc1234`, 2026-12-04 10:00 UTC, 71 s wall" in gt and "| 1 | 2 |" in gt
    assert "# its title" not in gt
    flt = doc.split("## `riskfield bench filter`")[1].split("\n## ")[0]
    assert "| `results/m/after/step_us` | 3 | 9.50 | 11.25 | 12.00 |" in flt  # timings from summary.json
    assert "| a | 1.00 | 2.00 |" in flt and "| b | 3.00 | 4.00 |" in flt
    # A section never run says so, and how to run it: no figure from elsewhere.
    nav = doc.split("## `riskfield bench navigation --perception gt`")[1].split("\n## ")[0]
    assert "Not measured by `benchmarks/regenerate.sh` yet: `SECTIONS=navigation_gt bash" in nav
    assert [ln for ln in nav.splitlines() if ln.startswith("|")] == []
    for s in R.SECTIONS:
        assert doc.count(f"## `{s.command}`\n") == 1


def test_unrun_sections_keep_their_last_stamped_run_and_drop_hand_written_ones(tmp_path: Path) -> None:
    first = tmp_path / "first"
    _run(first, "navigation_gt", commit="old1234")
    hand = ("\n\n## Another writer's block\n\n<!-- other:begin -->\n\nits table\n\n<!-- other:end -->\n"
            "\n## `riskfield bench teleop --perception gt` (462 s wall)\n\n<!-- run:teleop_gt:begin -->\n\n"
            "| typed | 0.5 |\n\n<!-- run:teleop_gt:end -->\n")
    previous = R.assemble(first) + hand
    second = tmp_path / "second"
    _run(second, "filter", commit="new5678")
    doc = R.assemble(second, previous)
    assert "`old1234`" in doc.split("## `riskfield bench navigation --perception gt`")[1].split("\n## ")[0]
    assert "`new5678`" in doc.split("## `riskfield bench filter`")[1].split("\n## ")[0]
    assert "| typed | 0.5 |" not in doc  # unstamped: not from a run of this script
    assert "## Another writer's block\n\n<!-- other:begin -->\n\nits table\n\n<!-- other:end -->" in doc
    assert R.assemble(second, doc) == doc  # regenerating from its own output changes nothing


def test_a_bench_that_writes_its_own_markers_keeps_them_when_not_rerun(tmp_path: Path) -> None:
    block = "<!-- crowd-core:begin -->\n\n| Family | written by the bench's --results |\n\n<!-- crowd-core:end -->"
    doc = R.assemble(tmp_path, f"## Crowd families (core): `riskfield bench crowd --mode core`\n\n{block}\n")
    assert doc.count("<!-- crowd-core:begin -->") == 1 and "written by the bench's --results" in doc


def test_a_failed_run_says_so_under_its_stamp(tmp_path: Path) -> None:
    _run(tmp_path, "link", tables=None, exit_code=1)
    link = R.assemble(tmp_path).split("## `riskfield bench link`")[1]
    assert "The command exited 1" in link and "log.txt" in link


def test_every_section_is_a_bench_that_takes_an_out_folder() -> None:
    from riskfield.cli import app

    runner = CliRunner()
    for s in R.SECTIONS:
        res = runner.invoke(app, ["bench", s.args.split()[0], "--help"], terminal_width=200)
        assert res.exit_code == 0 and "--out" in res.output, (s.name, res.output[-500:])


def test_the_script_lists_the_same_sections() -> None:
    out = subprocess.run([sys.executable, "-m", "riskfield.experiments.results", "--list"], capture_output=True,
                         text=True, check=True).stdout
    assert [line.split("\t") for line in out.splitlines()] == [[s.name, s.args] for s in R.SECTIONS]


def test_the_script_refuses_an_unknown_section(tmp_path: Path) -> None:
    proc = subprocess.run(["bash", str(REPO / "benchmarks" / "regenerate.sh")], capture_output=True, text=True,
                          env={**os.environ, "SECTIONS": "filtre", "OUT": str(tmp_path / "out"),
                               "RESULTS": str(tmp_path / "RESULTS.md"), "PY": sys.executable})
    assert proc.returncode == 2 and "no section 'filtre'" in proc.stderr
    assert not (tmp_path / "RESULTS.md").exists()


@pytest.mark.slow  # one short filter bench, about 30 s
def test_the_script_runs_a_section_stamps_it_and_rewrites_the_document(tmp_path: Path) -> None:
    results = tmp_path / "RESULTS.md"
    results.write_text("## Kept: `riskfield bench scale`\n\n<!-- scale:begin -->\n\nkept\n\n<!-- scale:end -->\n")
    proc = subprocess.run(["bash", str(REPO / "benchmarks" / "regenerate.sh")], capture_output=True, text=True,
                          env={**os.environ, "SECTIONS": "filter", "OUT": str(tmp_path / "out"),
                               "RESULTS": str(results), "PY": sys.executable,
                               "ARGS_filter": "--steps 20 --paced-hz 0"}, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    stamp = json.loads((tmp_path / "out" / "filter" / "stamp.json").read_text())
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=REPO,
                          check=True).stdout.strip()
    assert stamp["commit"].startswith(head) and stamp["exit"] == 0
    assert stamp["command"] == f"riskfield bench filter --steps 20 --paced-hz 0 --out {tmp_path / 'out' / 'filter'}"
    doc = results.read_text()
    assert f"*Measured at commit `{stamp['commit']}`" in doc and "after_vs_before" in doc
    assert "<!-- scale:begin -->\n\nkept\n\n<!-- scale:end -->" in doc
