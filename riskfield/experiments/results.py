"""Assemble ``benchmarks/RESULTS.md`` from benchmark output folders (``benchmarks/regenerate.sh``).

``python -m riskfield.experiments.results OUT [--previous benchmarks/RESULTS.md]`` prints the whole
document: the fixed text (what each protocol is, how this reproduction differs from the paper; no
measured number in it), then one section per run in ``SECTIONS``, each made only of what its run
wrote (``tables.md`` or ``table.md``, else tables rendered from its ``summary.json``) under the stamp
``regenerate.sh`` wrote beside it (``stamp.json``: the commit, the exact command, the date, the wall
time and the machine's load). A run with a ``before/`` folder (the same command at another commit,
``BEFORE=rev``) is shown beside it, stamped with its own commit.

A section not re-run this time is kept from ``--previous`` only if a run made it (it carries its
stamp, so it says which commit it measured); otherwise it says it has not been measured and how to
run it. Marked blocks of other writers in ``--previous`` (``<!-- name:begin -->`` …
``<!-- name:end -->``, e.g. a bench's ``--results``) are kept with their heading.
"""

from __future__ import annotations

import argparse
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Section:
    """One run of ``regenerate.sh``: its folder name under OUT and its ``riskfield bench`` arguments."""

    name: str
    args: str
    marker: str = ""  # a marked block this section fills (another writer's markers), else "run:<name>"

    @property
    def command(self) -> str:
        return f"riskfield bench {self.args}"

    @property
    def block(self) -> str:
        return self.marker or f"run:{self.name}"


#: Every section, in the document's order; ``benchmarks/regenerate.sh`` runs the same list
#: (``python -m riskfield.experiments.results --list``).
SECTIONS = (
    Section("safety_riskfield_gt", "safety --protocol riskfield --perception gt"),
    Section("safety_riskfield_sim", "safety --protocol riskfield --perception sim"),
    Section("safety_authors_gt", "safety --protocol authors --semantic both --perception gt"),
    Section("safety_authors_sim", "safety --protocol authors --semantic both --perception sim"),
    Section("teleop_gt", "teleop --perception gt"),
    Section("teleop_gt_paper", "teleop --preset paper --perception gt"),
    Section("teleop_sim", "teleop --perception sim"),
    Section("navigation_gt", "navigation --perception gt"),
    Section("navigation_sim", "navigation --perception sim"),
    Section("crowd_sim", "crowd --perception sim"),
    Section("crowd_gt", "crowd --perception gt"),
    Section("crowd_core", "crowd --mode core", marker="crowd-core"),
    Section("scale", "scale", marker="scale"),
    Section("scale_stack", "scale --mode stack", marker="scale-stack"),
    Section("latency_camera", "latency --path camera"),
    Section("latency_replay", "latency --path replay"),
    Section("mapping", "mapping"),
    Section("filter", "filter"),
    Section("link", "link"),
)

HEADER = """# Paper reproduction: measured results

This file is written by `bash benchmarks/regenerate.sh` (from the repository root), every section by the run it
shows: `SECTIONS="filter link" bash benchmarks/regenerate.sh` re-runs only those and keeps the others' last runs;
`bash benchmarks/regenerate.sh` re-runs them all (hours of CPU on a 2-core machine). Each section is stamped with
the commit it measured and the exact command; each run also writes `summary.json` (every number) and plots into
its folder under `bench_out/results/`. Wall times are the machine's under its load at the time (in the stamp).

## Two safety protocols, and why both exist

* `--protocol riskfield` (the default) is this project's benchmark: object-centric pairs balanced over the
  *fixed* risk groups of `RiskConfig` (person/animal high, furniture mid, ball/box low), robot radius 0.15 m,
  |a| ≤ 1.5 m/s², the safety filter core (`double3d`, its default *braking* barrier: the paper's HOCBF below its
  speed floor a_b/k₂) with identical gains for every method and an extra margin beyond the robot radius stated
  per method by one rule (δ = v_max·T plus half the field's cell, `voxel_size`: the ESDF's voxel, the point
  cloud's downsampling cell; `margin_m` in `summary.json`), every obstacle of the semantic ESDF inflated (what a
  deployed robot does), clearance to the obstacle surfaces (floor and ceiling excluded), progress clipped to
  [0, 1] at the end of the run. It measures the system as it is deployed. Each ESDF variant is also driven with
  *no* extra margin by the default filter and by the paper's filter (eq. 14's HOCBF on the trilinear field): the
  full-run table shows what the margin buys. The `hocbf` barrier gets its own row only when the bench's v_max is
  above the braking barrier's speed floor (`safety_benchmark.barriers_differ`): below it the two barriers are one
  and the row would repeat the default's roll-outs. Every method runs the same compiled filter step.
* `--protocol authors` is the paper's published protocol (phai-lab/SafeDF, `README_success6_final_experiment.md`
  and `recompute_paper_tables_from_rollouts.py`; see `riskfield/experiments/authors.py`): per-scene
  size-balanced risk groups (chunks of three ADE20K classes by median OBB diagonal, cyclic tier orders),
  object-ring pairs whose straight line collides (radius 0.03 m, margin 0.02 m, end clearance ≥ 0.20 m,
  50 per group rank-matched), SaferSplat's double-integrator HOCBF — the paper's eq. 14 *with* its Hessian
  term on the ESDF rows (α = 5, β = 1, no input bounds, the reference passed through on solver failure,
  0.05 s × 500 steps; `∇²h = 0` rows are a named extra variant beside them), progress = max ‖p_t − s‖/‖g − s‖ (not
  clipped), MP clearance with the *unsigned* distance to the full mesh (as the authors' script; the paper's
  text says signed). Semantic modes: `target` inflates only the trajectory's target group (the authors'),
  `scene` inflates every group (deployed). It exists so the paper's numbers can be compared like with like;
  the riskfield protocol exists because the authors' protocol scores a filter that never sees the other
  groups' margins, which a deployed robot does.
* Reading the low-group rows: in `target` mode they are the ESDF's by construction; in `scene` mode they show
  what inflating the *other* groups costs a trajectory aimed at a low-risk object.

## Differences from the paper (one line each)

* Scenes: six procedural rooms (`random_room`, seeds 0–5), not the six ScanNet++ scans (`--scannetpp DIR` runs
  those for users who have the data; its labels map to ADE20K by `riskfield/experiments/scannetpp_labels.py`).
* `--protocol riskfield`'s baseline is a nearest-point point-cloud CBF (KD-tree, floor removed by height);
  `--protocol authors` has the SaferSplat-style baseline below.
* Accepted trajectories differ from the paper's 486 because the scenes differ; counts are in each run.
* Perception: rendered pointmaps (`gt`) or the FM-like degradation (`sim`), not MASt3R-SLAM on iPhone video.
* Map budget: every method gets the same frames within the same integration budget; the Gaussians get the
  plain ESDF's reconstruction wall time (integration + ESDF) in the same run.
* Baseline: a SaferSplat-*style* map (per-cell anisotropic Gaussians fitted to the observed points, not a
  photometrically trained 3DGS) with SaferSplat's ellipsoid-distance HOCBF over the 12 nearest Gaussians
  (SaferSplat: all Gaussians with polytope pruning, on a GPU), so its time is not comparable with the paper's.
* The SaferSplat-style baseline's MP collision rate is not SaferSplat's (the paper: 0.216) and is not meant as a
  reproduction of it. What differs by construction (`riskfield/experiments/safersplat.py`): one Gaussian per
  0.1 m cell holding at least 6 observed points, so surfaces seen by few pixels (far, grazing, thin parts, the
  unseen sides) have no Gaussian, where a trained 3DGS is optimised over many views to cover what renders; the
  ellipsoid spans √3·σ of its cell's points (a wall cell is a disc ~1 cm thick, and neighbouring discs only just
  meet), not a photometric fit; the robot's radius is added to the semi-axes (an approximation of the Minkowski
  sum); and only the 12 Gaussians with the nearest *means* get a row (SaferSplat keeps all, pruned by polytope),
  so a large ellipsoid whose mean is farther than 12 small ones is absent from the step. The pairs are chosen to
  collide with the full mesh, so every gap of the map is on some pair's path. Which of these accounts for how
  much of the difference has not been measured; the ESDF rows are built from the same frames and budget.
* Computation time is measured in Python on a shared 2-core CPU (the paper: CUDA + CVXPY/Clarabel).
* OBB diagonals come from each mesh object's vertices (open3d OBB), not the annotation's `obb.axesLengths`.
* Roll-outs end early once nothing can change (at rest at the goal, or at rest for 2 s); the authors always run
  500 steps.
* The nominal input is riskfield's goal-seeking PD law; the authors' `goal` mode is not published in detail.
* The ESDF rows of the authors' HOCBF read distance, gradient and Hessian from the trilinear ESDF (the paper: "ESDF
  gradients and Hessians are computed by finite differences and evaluated at query points using trilinear
  interpolation"); the authors' ESDF controller (`run_scannetpp_esdf_cbf_ref.py`) is not in their release. The
  `∇²h = 0` rows are the same controller without the curvature term, reported beside it. With SaferSplat's
  unbounded QP a few Hessian roll-outs are flung away on a spike of the grid's Hessian (the *Runaway* column);
  their unclipped progress is in the mean, so read the progress of those rows with it.
* Table III matches progress over the three methods (baseline, ESDF, semantic ESDF), as the authors'
  `recompute_paper_tables_from_rollouts.py` does; the two-ESDF matching of the paper's caption is a second, named
  table. Table II extra rows are matched with the other two methods in place of their own (a `∇²h = 0` row) or of
  the third.
* The paper's full-run figures come from the authors' `success6_3methods_exposure_main_table.csv` (collision rate
  over the whole run, minimum clearance as a per-trajectory mean): compare them with the "Min. Clearance, mean"
  column, not with the minimum over all trajectories, which they do not publish.
* Clearance is unsigned (the authors' script): a robot deep inside a solid object is scored by its distance to
  the nearest surface; the full-run collision rate counts any step closer than the radius.
* The low group's ESDF and semantic rows in `target` mode are identical by construction (margin 0): the
  target-mode roll-out over a low-group target is the plain ESDF's roll-out.
"""

_BLOCK = re.compile(r"<!-- (?P<name>[\w:.-]+):begin -->\n(?P<body>.*?)\n?<!-- (?P=name):end -->", re.S)


def _demote(md: str) -> str:
    """A run's tables without its own title line, its headings one level below the section's."""
    lines = md.strip().splitlines()
    if lines and lines[0].startswith("# "):
        lines = lines[1:]
    return "\n".join("#" + ln if ln.startswith("## ") else ln for ln in lines).strip()


def _num(x: Any) -> str:
    if isinstance(x, bool) or not isinstance(x, int | float):
        return str(x)
    if isinstance(x, int):
        return str(x)
    if not math.isfinite(x):
        return "–"
    return f"{x:.3g}" if abs(x) < 1e-2 and x != 0 else f"{x:.2f}" if abs(x) < 1e4 else f"{x:.3g}"


def _is_timing(d: Any) -> bool:
    return isinstance(d, dict) and {"median", "p99"} <= d.keys()


def _scalars(d: Any) -> bool:
    return isinstance(d, dict) and bool(d) and all(isinstance(v, int | float | str | bool) or v is None
                                                   for v in d.values())


def summary_tables(summary: dict[str, Any]) -> str:
    """Tables of a ``summary.json`` whose bench writes no markdown: every timing (``timing_stats``:
    n, median, p99, max) in one table by its path, and every mapping of rows of scalars with the same
    columns as a table of its own. Only what the run wrote; nothing is recomputed."""
    timings: list[tuple[str, dict]] = []
    tables: list[tuple[str, dict[str, dict]]] = []

    def walk(path: str, node: Any, depth: int) -> None:
        if _is_timing(node):
            timings.append((path, node))
            return
        if not isinstance(node, dict) or depth > 6:
            return
        rows = {k: v for k, v in node.items() if _scalars(v) and not _is_timing(v)}
        if len(rows) >= 2 and len({tuple(v) for v in rows.values()}) == 1:
            tables.append((path, rows))
        for k, v in node.items():
            if k not in rows:
                walk(f"{path}/{k}" if path else str(k), v, depth + 1)

    walk("", summary, 0)
    out: list[str] = []
    if timings:
        out += ["| measured | n | median | p99 | max |", "|---|---|---|---|---|"]
        out += [f"| `{p}` | {_num(t.get('n', '–'))} | {_num(t['median'])} | {_num(t['p99'])} | "
                f"{_num(t.get('max', math.nan))} |" for p, t in timings]
    for path, rows in tables:
        cols = list(next(iter(rows.values())))
        out += ["", f"`{path or 'summary'}`:", "", "| | " + " | ".join(cols) + " |",
                "|---|" + "---|" * len(cols)]
        out += [f"| {k} | " + " | ".join(_num(v.get(c)) for c in cols) + " |" for k, v in rows.items()]
    return "\n".join(out).strip() or "(the run's summary.json holds no table)"


def _stamp_line(stamp: dict[str, Any]) -> str:
    load = stamp.get("load")
    return (f"*Measured at commit `{stamp.get('commit', '?')}`, {stamp.get('date', '?')}, "
            f"{_num(stamp.get('wall_s', math.nan))} s wall" + (f", load {load}" if load else "")
            + f"; command: `{stamp.get('command', '?')}`.*")


def _run_body(run: Path) -> str | None:
    """The stamped tables of one run folder, or None when it holds no finished run."""
    stamp_file = run / "stamp.json"
    if not stamp_file.is_file():
        return None
    stamp = json.loads(stamp_file.read_text())
    head = _stamp_line(stamp)
    if stamp.get("exit", 0) != 0:  # e.g. `bench link` exits 1 over its budget, with its tables written
        head += f" *The command exited {stamp['exit']}; its output is in `{run}/log.txt`.*"
    for name in ("tables.md", "table.md"):
        if (run / name).is_file():
            return f"{head}\n\n{_demote((run / name).read_text())}"
    if (run / "summary.json").is_file():
        return f"{head}\n\n{summary_tables(json.loads((run / 'summary.json').read_text()))}"
    return f"{head}\n\nThe run wrote no tables."


def previous_blocks(text: str) -> dict[str, tuple[str, str]]:
    """Marked blocks of a previous RESULTS.md: name → (the heading above it, its body)."""
    out: dict[str, tuple[str, str]] = {}
    for m in _BLOCK.finditer(text):
        heading = next((ln for ln in reversed(text[: m.start()].splitlines()) if ln.startswith("## ")), "")
        out[m["name"]] = (heading, m["body"].strip())
    return out


def _block(name: str, body: str) -> str:
    return f"<!-- {name}:begin -->\n\n{body.strip()}\n\n<!-- {name}:end -->"


def assemble(out: Path, previous: str = "") -> str:
    prev = previous_blocks(previous)
    doc = [HEADER.rstrip()]
    for s in SECTIONS:
        body = _run_body(out / s.name)
        if body is not None:
            before = _run_body(out / s.name / "before")
            if before is not None:
                body += f"\n\n### Before: the same command at another commit, in the same run\n\n{before}"
        elif s.block in prev and (s.marker or "*Measured at commit" in prev[s.block][1]):
            # Not re-run this time: a run's section with its own stamp, or what the bench itself wrote
            # into its markers (``--results``).
            body = prev[s.block][1]
        else:
            body = (f"Not measured by `benchmarks/regenerate.sh` yet: `SECTIONS={s.name} bash "
                    "benchmarks/regenerate.sh` runs it (earlier hand-written figures are in this file's git history).")
        doc.append(f"## `{s.command}`\n\n{_block(s.block, body)}")
    ours = {s.block for s in SECTIONS}
    for name, (heading, body) in prev.items():
        if name not in ours:
            doc.append(f"{heading}\n\n{_block(name, body)}".strip())
    return "\n\n".join(doc).rstrip() + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, nargs="?")
    ap.add_argument("--previous", type=Path, default=None)
    ap.add_argument("--list", action="store_true", help="print each section's name and bench arguments, tab-separated")
    args = ap.parse_args()
    if args.list:
        print("\n".join(f"{s.name}\t{s.args}" for s in SECTIONS))
        return
    if args.out is None:
        ap.error("OUT is required")
    prev = args.previous.read_text() if args.previous and args.previous.is_file() else ""
    print(assemble(args.out, prev), end="")


if __name__ == "__main__":
    main()
