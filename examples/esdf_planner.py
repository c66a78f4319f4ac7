"""Plan a path on riskfield's semantic ESDF, depending on nothing of riskfield but its protocol.

    python examples/esdf_planner.py --connect tcp/127.0.0.1:7447 --start 0 0 --goal 3 1 \\
        --clearance 0.2 [--send-goal]

Subscribes to ``rf/{robot}/map/esdf``, takes the newest grid, and runs A* over the grid cells
at the robot's height (a 2-D slice has nz = 1). A cell is traversable when its signed
distance is at least ``clearance`` — the ESDF already carries the class-dependent inflation,
so the path keeps more room from people and pets than from walls. The step cost grows near
obstacles so the path prefers open space. With ``--send-goal`` the path is sent to the
navigator as a ``NavGoal``.

The start and the goal are checked with the field API (``riskfield.services.fields``: the
interpolated distance and the in-map rule the safety filter uses), so the planner refuses exactly
the ends the filter would brake at. Only ``riskfield.protocol`` and ``riskfield.services.fields``
(numpy, pydantic, msgpack) and ``eclipse-zenoh`` are needed.
"""

from __future__ import annotations

import argparse
import heapq
import json
import sys
import threading

import numpy as np

from riskfield.protocol import ENCODING, EsdfGrid, Keys, NavGoal, decode, encode
from riskfield.services.fields import EsdfField


def _slice(grid: EsdfGrid, z: float) -> np.ndarray:
    """Distance over (x, y) at height z (the only layer of a 2-D grid)."""
    k = 0 if grid.distance.shape[2] == 1 else round((z - grid.origin[2]) / grid.voxel_size)
    k = min(max(k, 0), grid.distance.shape[2] - 1)
    return np.asarray(grid.distance[:, :, k], dtype=float)


def bounds(grid: EsdfGrid) -> tuple[tuple[float, float], tuple[float, float]]:
    """The (x, y) ranges the grid's cells cover, map frame: cell i spans o + (i ± ½)·s."""
    nx, ny = grid.distance.shape[:2]
    ox, oy, vs = grid.origin[0], grid.origin[1], grid.voxel_size
    return (ox - vs / 2, ox + (nx - 0.5) * vs), (oy - vs / 2, oy + (ny - 0.5) * vs)


def unplannable(grid: EsdfGrid, start: tuple[float, float], goal: tuple[float, float], clearance: float,
                z: float = 0.0) -> str | None:
    """Why no path can exist before searching: an end outside the map or too close to an
    obstacle; ``None`` when both ends are usable."""
    (x0, x1), (y0, y1) = bounds(grid)
    d = _slice(grid, z)
    for name, (x, y) in (("start", start), ("goal", goal)):
        if not (x0 <= x < x1 and y0 <= y < y1):
            return (f"the {name} ({x:g}, {y:g}) is outside the map, which covers x {x0:.2f}..{x1:.2f} m "
                    f"and y {y0:.2f}..{y1:.2f} m")
        i = min(round((x - grid.origin[0]) / grid.voxel_size), d.shape[0] - 1)
        j = min(round((y - grid.origin[1]) / grid.voxel_size), d.shape[1] - 1)
        if d[i, j] < clearance:
            return (f"the {name} ({x:g}, {y:g}) is {max(d[i, j], 0.0):.2f} m from an obstacle, "
                    f"less than the clearance {clearance:g} m")
    return None


def plan(grid: EsdfGrid, start: tuple[float, float], goal: tuple[float, float], clearance: float,
         z: float = 0.0, weight: float = 0.5) -> np.ndarray | None:
    """A* on the 8-connected cells of the slice; ``None`` when no path keeps ``clearance``
    (or the start or the goal is outside the map).

    Returns an (K, 2) array of cell centres from start to goal (map frame, metres).
    """
    ends = EsdfField.from_grid(grid).query(np.array([[*start, z], [*goal, z]], dtype=float))
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
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"')
    cfg.insert_json5("connect/endpoints", json.dumps([args.connect]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    got: list[EsdfGrid] = []
    ready = threading.Event()

    def on_grid(sample: zenoh.Sample) -> None:
        try:
            got.append(decode(sample.payload.to_bytes(), EsdfGrid))
            ready.set()
        except ValueError as exc:
            print(f"ignored a bad ESDF message: {exc}", file=sys.stderr)

    with zenoh.open(cfg) as session:
        sub = session.declare_subscriber(keys.esdf, on_grid)
        if not ready.wait(args.timeout):
            print(f"no ESDF on {keys.esdf} within {args.timeout} s", file=sys.stderr)
            return 2
        sub.undeclare()
        grid = got[-1]
        reason = unplannable(grid, tuple(args.start), tuple(args.goal), args.clearance, args.z)
        if reason is not None:
            print(f"no path: {reason}", file=sys.stderr)
            return 1
        path = plan(grid, tuple(args.start), tuple(args.goal), args.clearance, args.z)
        if path is None:
            print(f"no path keeps the clearance {args.clearance:g} m between start and goal", file=sys.stderr)
            return 1
        waypoints = simplify(path)
        print(json.dumps({"cells": len(path), "waypoints": waypoints.round(3).tolist()}))
        if args.send_goal:
            goal = NavGoal(waypoints=np.column_stack([waypoints, np.zeros(len(waypoints))]), tolerance=0.1,
                           loop=False)
            session.put(keys.nav_goal, encode(goal), encoding=zenoh.Encoding(ENCODING))
    return 0


if __name__ == "__main__":
    sys.exit(main())
