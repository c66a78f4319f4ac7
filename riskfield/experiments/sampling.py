"""Object-centric start/goal sampling (the paper's benchmark protocol).

Every trajectory is built around one *target object*: the start and the goal lie on opposite
sides of it, so the straight line between them passes through or close by the object and
the safety filter has to act. The trajectory inherits the target's risk group, which is
what the per-group table aggregates over. Structural elements (walls, floor, ceiling, doors,
windows, columns) are never targets, as in the paper. Targets are drawn round-robin over the
risk groups present so the groups stay balanced.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import RiskConfig, ade20k

STRUCTURE = frozenset(ade20k.index(n) for n in (
    "wall", "floor", "ceiling", "door", "windowpane", "column", "building", "stairs", "step", "railing",
    "rug", "curtain", "screen door",
))


@dataclass(frozen=True)
class Target:
    """An object trajectories can be sampled around: footprint centre and radius, height."""

    index: int  # index of the object in the scene
    name: str
    label: int
    group: str
    centre: np.ndarray  # (x, y) of the bounding-box centre
    radius: float  # horizontal half-diagonal of the bounding box
    top: float  # highest z of the object


@dataclass(frozen=True)
class Pair:
    """One start/goal pair, shared by every compared method."""

    pair: int
    target: str
    group: str
    start: np.ndarray
    goal: np.ndarray


def targets_from_boxes(objects: Sequence[tuple[str, int, np.ndarray, np.ndarray]], risk: RiskConfig) -> list[Target]:
    """Targets from ``(name, label, lo, hi)`` bounding boxes: obstacles of some risk group that
    are not structure."""
    lut = risk.label_to_group()
    out = []
    for i, (name, label, lo, hi) in enumerate(objects):
        gid = int(lut[int(label)])
        if gid == 0 or int(label) in STRUCTURE:
            continue
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        out.append(Target(i, name, int(label), risk.groups[gid - 1].name, (lo[:2] + hi[:2]) / 2,
                          float(np.linalg.norm(hi[:2] - lo[:2]) / 2), float(hi[2])))
    return out


@dataclass(frozen=True)
class PairRule:
    """Where the ends of a pair may lie: both keep ``robot_radius + min_free`` of ground-truth clearance
    and lie inside the bounds; ``standoff`` is the gap from the object's footprint circle to each end;
    ``lateral`` (× radius) offsets the line sideways so some pass through the object and some graze it;
    ``max_tries`` draws per slot before a group counts as unplaceable."""

    robot_radius: float
    bounds_lo: np.ndarray
    bounds_hi: np.ndarray
    standoff: tuple[float, float] = (0.35, 1.0)
    lateral: float = 0.5
    min_free: float = 0.1
    max_tries: int = 2000


def sample_pairs(targets: Sequence[Target], n: int, clearance: Callable[[np.ndarray], np.ndarray],
                 rng: np.random.Generator, rule: PairRule, first_id: int = 0) -> list[Pair]:
    """``n`` pairs around ``targets`` that keep ``rule``; ``clearance(points)`` is the ground-truth signed
    distance to the obstacle set. The height is inside the object's vertical extent when that leaves
    room for the robot, so the object blocks the way."""
    if not targets:
        return []
    groups = sorted({t.group for t in targets})
    by_group = {g: [t for t in targets if t.group == g] for g in groups}
    pairs: list[Pair] = []
    failed: set[str] = set()
    slot = 0
    while len(pairs) < n and len(failed) < len(groups):
        group = groups[slot % len(groups)]
        slot += 1
        if group in failed:
            continue
        # Fill this slot from any target of the group (objects against a wall only admit
        # directions along it); a group with no placeable pair at all is dropped.
        for _ in range(rule.max_tries):
            t = by_group[group][int(rng.integers(len(by_group[group])))]
            pair = _try_pair(t, rng, rule, clearance)
            if pair is not None:
                start, goal = pair
                pairs.append(Pair(first_id + len(pairs), t.name, t.group, start, goal))
                break
        else:
            failed.add(group)
    return pairs


def _try_pair(t: Target, rng: np.random.Generator, rule: PairRule,
              clearance: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    robot_radius, lo, hi, standoff, lateral, min_free = (rule.robot_radius, rule.bounds_lo, rule.bounds_hi,
                                                         rule.standoff, rule.lateral, rule.min_free)
    theta = rng.uniform(0, 2 * np.pi)
    u = np.array([np.cos(theta), np.sin(theta)])
    off = rng.uniform(-lateral, lateral) * t.radius * np.array([-u[1], u[0]])
    d_s = t.radius + robot_radius + rng.uniform(*standoff)
    d_g = t.radius + robot_radius + rng.uniform(*standoff)
    z_lo = robot_radius + min_free
    z_hi = max(z_lo, min(t.top - 0.05, hi[2] - z_lo))
    z = rng.uniform(z_lo, z_hi)
    start = np.array([*(t.centre - d_s * u + off), z])
    goal = np.array([*(t.centre + d_g * u + off), z])
    ends = np.stack([start, goal])
    if np.any(ends < lo) or np.any(ends > hi):
        return None
    if not np.all(clearance(ends) > robot_radius + min_free):
        return None
    return start, goal
