"""The paper's simulation metrics (Section "Metrics"), on recorded trajectories.

* **Computation time** — mean per-step runtime of the safety filter.
* **Progress to goal** — normalised distance travelled toward the goal,
  ``(‖s − g‖ − ‖p_T − g‖) / ‖s − g‖`` clipped to [0, 1], at the end ``T`` of the roll-out.
* **Matched-progress (MP) clearance** — the methods compared on one start/goal pair reach
  different portions of it. Each method's *reached progress* is the largest progress along
  its path; the *common progress* is the smallest of those over the compared methods. A
  method's MP clearance is the smallest ground-truth signed distance to the mesh, minus the
  robot radius, over its path up to the first step at which it reaches the common progress.
  So a method that stops early cannot score a better clearance by never entering the hard
  part of the path.
* **MP collision rate** — the fraction of trajectories whose MP clearance is negative.

Beside the paper's matched-progress metrics, the honest safety figures over the *whole* run
(a method that stops early is not excused for what it hit before or after the common progress):

* **Full-run collision rate** — the fraction of trajectories with any step whose clearance
  (ground-truth distance to the obstacle surfaces minus the robot radius) is below zero.
* **Minimum clearance** — the smallest clearance over every step of every trajectory; beside it,
  the per-trajectory minimum averaged over the trajectories (``min_clearance_mean_m``: the
  statistic of the authors' ``min_clearance_mean_full_m``).
* **Relaxed-step fraction** — the fraction of filter steps that could not certify the nominal
  barrier (slack-relaxed QP or a braking fallback).

Aggregates are means over trajectories, overall and per risk group (the group of the
object a trajectory was sampled around).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np


def progress_curve(path: np.ndarray, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Progress at every step of ``path`` (N×D), clipped to [0, 1]."""
    d0 = float(np.linalg.norm(np.asarray(start, dtype=float) - goal))
    if d0 <= 0.0:
        return np.ones(len(path))
    d = np.linalg.norm(np.asarray(path, dtype=float) - goal, axis=1)
    return np.clip((d0 - d) / d0, 0.0, 1.0)


def progress_to_goal(path: np.ndarray, start: np.ndarray, goal: np.ndarray) -> float:
    """Progress at the last step of the roll-out."""
    return float(progress_curve(path[-1:], start, goal)[0])


def matched_end_index(curve: np.ndarray, common: float) -> int:
    """Index of the first step whose progress reaches ``common`` (the last step if none does,
    which only happens through floating-point round-off since ``common ≤ max(curve)``)."""
    hit = np.flatnonzero(curve >= common - 1e-9)
    return int(hit[0]) if hit.size else len(curve) - 1


def mp_clearance(clearance: np.ndarray, curve: np.ndarray, common: float) -> float:
    """Smallest clearance (GT signed distance − robot radius) up to the common progress."""
    end = matched_end_index(curve, common)
    return float(np.min(clearance[: end + 1]))


@dataclass
class Rollout:
    """One method's roll-out on one start/goal pair. ``clearance[i]`` is the ground-truth
    signed distance to the mesh minus the robot radius at ``path[i]``."""

    method: str
    pair: int  # id of the start/goal pair shared by every method
    group: str  # risk group of the target object
    path: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    clearance: np.ndarray
    filter_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    scene: str = ""
    relaxed_steps: int = 0  # filter steps that fell back (slack-relaxed QP or braking)

    @property
    def min_clearance(self) -> float:
        """Smallest clearance over the whole run."""
        return float(self.clearance.min())

    @property
    def curve(self) -> np.ndarray:
        return progress_curve(self.path, self.start, self.goal)

    @property
    def progress(self) -> float:
        return progress_to_goal(self.path, self.start, self.goal)

    @property
    def reached(self) -> float:
        return float(self.curve.max())


def matched(rollouts: Sequence[Rollout], methods: Sequence[str]) -> dict[tuple[str, int], float]:
    """MP clearance of every (method, pair) among ``methods``; pairs must have all methods."""
    by_pair: dict[int, dict[str, Rollout]] = {}
    for r in rollouts:
        if r.method in methods:
            by_pair.setdefault(r.pair, {})[r.method] = r
    out: dict[tuple[str, int], float] = {}
    for pair, runs in by_pair.items():
        missing = set(methods) - set(runs)
        if missing:
            raise ValueError(f"pair {pair} has no roll-out of {sorted(missing)}")
        curves = {m: runs[m].curve for m in methods}
        common = min(float(c.max()) for c in curves.values())
        for m in methods:
            out[(m, pair)] = mp_clearance(runs[m].clearance, curves[m], common)
    return out


@dataclass(frozen=True)
class Summary:
    """The four metrics over a set of trajectories (``n`` of them)."""

    n: int
    computation_time_s: float
    progress: float
    mp_clearance_m: float
    mp_collision_rate: float
    filter_time_p99_s: float = 0.0
    collision_rate: float = float("nan")  # full run: any step with clearance < 0
    min_clearance_m: float = float("nan")  # full run, over every trajectory
    relaxed_fraction: float = float("nan")  # of all filter steps
    min_clearance_mean_m: float = float("nan")  # full run: each trajectory's minimum, averaged

    def as_dict(self) -> dict[str, float]:
        return dict(n=self.n, computation_time_s=self.computation_time_s, progress=self.progress,
                    mp_clearance_m=self.mp_clearance_m, mp_collision_rate=self.mp_collision_rate,
                    filter_time_p99_s=self.filter_time_p99_s, collision_rate=self.collision_rate,
                    min_clearance_m=self.min_clearance_m, relaxed_fraction=self.relaxed_fraction,
                    min_clearance_mean_m=self.min_clearance_mean_m)


def summarise(rollouts: Iterable[Rollout], mp: dict[tuple[str, int], float], method: str,
              group: str | None = None) -> Summary:
    """Metrics of ``method`` (optionally restricted to one risk group) given MP clearances."""
    runs = [r for r in rollouts if r.method == method and (group is None or r.group == group)]
    if not runs:
        return Summary(0, float("nan"), float("nan"), float("nan"), float("nan"))
    times = np.concatenate([r.filter_times for r in runs]) if runs else np.zeros(0)
    clear = np.array([mp[(method, r.pair)] for r in runs])
    full = np.array([r.min_clearance for r in runs])
    steps = sum(len(r.filter_times) for r in runs)
    return Summary(
        n=len(runs),
        computation_time_s=float(times.mean()) if times.size else float("nan"),
        progress=float(np.mean([r.progress for r in runs])),
        mp_clearance_m=float(clear.mean()),
        mp_collision_rate=float(np.mean(clear < 0.0)),
        filter_time_p99_s=float(np.percentile(times, 99)) if times.size else float("nan"),
        collision_rate=float(np.mean(full < 0.0)),
        min_clearance_m=float(full.min()),
        relaxed_fraction=sum(r.relaxed_steps for r in runs) / steps if steps else float("nan"),
        min_clearance_mean_m=float(full.mean()),
    )
