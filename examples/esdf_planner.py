"""Plan a path on riskfield's semantic ESDF with the planner client (``riskfield.client``).

    python examples/esdf_planner.py --connect tcp/127.0.0.1:7447 --start 0 0 --goal 3 1 \\
        --clearance 0.2 [--send-goal]

Subscribes to ``rf/{robot}/map/esdf`` (``EsdfClient``), takes the first grid, and runs A* over the
grid cells at the robot's height (a 2-D slice has nz = 1). A cell is traversable when its signed
distance is at least ``clearance`` — the ESDF already carries the class-dependent inflation,
so the path keeps more room from people and pets than from walls. The step cost grows near
obstacles so the path prefers open space. The cell path is then shortened to the waypoints whose
straight segments the client calls clear with the clearance (``EsdfMap.segment_clear``, the
filter's interpolation and in-map rule), so the planner refuses exactly the ends the filter
would brake at. With ``--send-goal`` the waypoints go to the navigator as a ``NavGoal``.

Needs ``riskfield`` without extras (``riskfield.client`` and ``riskfield.protocol``: numpy,
pydantic, msgpack and ``eclipse-zenoh``); nothing of the services. ``riskfield[client]`` adds numba,
which compiles the field queries.
"""

from __future__ import annotations

import argparse
import heapq
import json
import sys

import numpy as np

from riskfield.client import EsdfClient, EsdfMap
from riskfield.protocol import ENCODING, EsdfGrid, Keys, NavGoal, encode


def _slice(grid: EsdfGrid, z: float) -> np.ndarray:
    """Distance over (x, y) at height z (the only layer of a 2-D grid)."""
    k = 0 if grid.distance.shape[2] == 1 else round((z - grid.origin[2]) / grid.voxel_size)
    k = min(max(k, 0), grid.distance.shape[2] - 1)
    return np.asarray(grid.distance[:, :, k], dtype=float)


def bounds(grid: EsdfGrid) -> tuple[tuple[float, float], tuple[float, float]]:
    """The (x, y) ranges of the map, map frame: the outer voxel centres (the filter's in-map rule)."""
    lo, hi = EsdfMap(grid).bounds()
    return (float(lo[0]), float(hi[0])), (float(lo[1]), float(hi[1]))


def unplannable(grid: EsdfGrid, start: tuple[float, float], goal: tuple[float, float], clearance: float,
                z: float = 0.0) -> str | None:
    """Why no path can exist before searching: an end outside the map or too close to an
    obstacle (the client's interpolated distance); ``None`` when both ends are usable."""
    m = EsdfMap(grid)
    (x0, x1), (y0, y1) = bounds(grid)
    ends = m.query([[*start, z], [*goal, z]])
    for k, (name, (x, y)) in enumerate((("start", start), ("goal", goal))):
        if not ends.inside[k]:
            return (f"the {name} ({x:g}, {y:g}) is outside the map, which covers x {x0:.2f}..{x1:.2f} m "
                    f"and y {y0:.2f}..{y1:.2f} m")
        if ends.distance[k] < clearance:
            return (f"the {name} ({x:g}, {y:g}) is {max(ends.distance[k], 0.0):.2f} m from an obstacle, "
                    f"less than the clearance {clearance:g} m")
    return None


def plan(grid: EsdfGrid, start: tuple[float, float], goal: tuple[float, float], clearance: float,
         z: float = 0.0, weight: float = 0.5) -> np.ndarray | None:
    """A* on the 8-connected cells of the slice; ``None`` when no path keeps ``clearance``
    (or the start or the goal is outside the map).

    Returns an (K, 2) array of cell centres from start to goal (map frame, metres).
    """
    ends = EsdfMap(grid).query([[*start, z], [*goal, z]])
    if not ends.inside.all() or (ends.distance < clearance).any():
        return None
    d = _slice(grid, z)
    ox, oy, vs = grid.origin[0], grid.origin[1], grid.voxel_size
    nx, ny = d.shape

    def cell(p: tuple[float, float]) -> tuple[int, int]:
        return round((p[0] - ox) / vs), round((p[1] - oy) / vs)

    s, g = cell(start), cell(goal)
    free = d >= clearance
    penalty = weight / np.maximum(d, vs)  # prefer open space
    steps = [(dx, dy, float(np.hypot(dx, dy))) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]
    best = {s: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(0.0, s)]
    while heap:
        _, c = heapq.heappop(heap)
        if c == g:
            path = [c]
            while path[-1] != s:
                path.append(parent[path[-1]])
            cells = np.array(path[::-1], dtype=float)
            return np.column_stack([ox + cells[:, 0] * vs, oy + cells[:, 1] * vs])
        for dx, dy, length in steps:
            n = (c[0] + dx, c[1] + dy)
            if not (0 <= n[0] < nx and 0 <= n[1] < ny) or not free[n]:
                continue
            cost = best[c] + length * (1.0 + penalty[n])
            if cost < best.get(n, np.inf):
                best[n] = cost
                parent[n] = c
                h = float(np.hypot(g[0] - n[0], g[1] - n[1]))
                heapq.heappush(heap, (cost + h, n))
    return None


def simplify(path: np.ndarray, every: int = 5) -> np.ndarray:
    """Every ``every``-th point plus the goal: waypoints for a navigator."""
    keep = list(range(0, len(path), every))
    if keep[-1] != len(path) - 1:
        keep.append(len(path) - 1)
    return path[keep]


def shortcut(m: EsdfMap, path: np.ndarray, clearance: float, z: float = 0.0) -> tuple[np.ndarray, float]:
    """The fewest waypoints of ``path`` (greedily, from the start) whose straight segments the client
    calls clear with ``clearance``; a cell step that is not clear itself (the interpolant between
    two free cell centres can dip below them) is kept as it is. Returns the waypoints and the
    smallest distance sampled along their segments."""
    keep, lowest, i = [0], np.inf, 0
    while i < len(path) - 1:
        for j in range(len(path) - 1, i, -1):
            check = m.segment_clear((*path[i], z), (*path[j], z), margin=clearance)
            if check.clear or j == i + 1:
                lowest = min(lowest, check.min_distance)
                keep.append(j)
                i = j
                break
    return path[keep], float(lowest)


def main(argv: list[str] | None = None) -> int:
    import zenoh

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447")
    ap.add_argument("--robot", default="limo1")
    ap.add_argument("--prefix", default="rf")
    ap.add_argument("--start", nargs=2, type=float, required=True)
    ap.add_argument("--goal", nargs=2, type=float, required=True)
    ap.add_argument("--z", type=float, default=0.1)
    ap.add_argument("--clearance", type=float, default=0.2)
    ap.add_argument("--timeout", type=float, default=10.0)
    ap.add_argument("--send-goal", action="store_true")
    args = ap.parse_args(argv)

    keys = Keys(robot=args.robot, prefix=args.prefix)
    with EsdfClient(args.connect, robot=args.robot, prefix=args.prefix) as esdf:
        print(f"waiting for an ESDF on {esdf.key}", file=sys.stderr, flush=True)
        m = esdf.wait(args.timeout)
        if m is None:
            print(f"no ESDF on {esdf.key} within {args.timeout} s", file=sys.stderr)
            return 2
        grid = m.grid
        reason = unplannable(grid, tuple(args.start), tuple(args.goal), args.clearance, args.z)
        if reason is not None:
            print(f"no path: {reason}", file=sys.stderr)
            return 1
        path = plan(grid, tuple(args.start), tuple(args.goal), args.clearance, args.z)
        if path is None:
            print(f"no path keeps the clearance {args.clearance:g} m between start and goal", file=sys.stderr)
            return 1
        waypoints, lowest = shortcut(m, path, args.clearance, args.z)
        print(json.dumps({"cells": len(path), "waypoints": waypoints.round(3).tolist(),
                          "min_distance": round(lowest, 4), "stamp_ns": m.stamp_ns}))
        if args.send_goal:
            goal = NavGoal(waypoints=np.column_stack([waypoints, np.zeros(len(waypoints))]), tolerance=0.1,
                           loop=False)
            esdf.session.put(keys.nav_goal, encode(goal), encoding=zenoh.Encoding(ENCODING))
    return 0


if __name__ == "__main__":
    sys.exit(main())
