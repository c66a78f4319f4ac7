"""Pure conversions from riskfield messages to things one can draw (no Rerun import here).

Frames: ``world`` is the map frame (x forward, y left, z up); ``world/robot`` is the base frame
(``T_WR`` from ``RobotState``); the camera is an optical frame (x right, y down, z forward, the
pinhole convention) placed in the robot frame by ``T_RC = T_WR⁻¹ · T_WC``.

The ESDF slice at height z is a Rerun ``GridMap`` of distances as stored (metres). Rerun draws
a grid map's first image row at the top: the texture's top-left corner at grid
``(0, height·cell_size)`` and its rows running along −y from there, with ``translation`` the
lower-left corner (upstream: rerun-io/rerun, crates/viewer/re_view_spatial/src/visualizers/
grid_map.rs, ``textured_rect_from_grid_map``). So image row ``r`` holds y index ``ny − 1 − r``
and column ``i`` x index ``i``, like a map seen from above with y up; the lower-left corner is
``(o_x − s/2, o_y − s/2)``, the corner of cell (0, 0), whose centre is the origin ``o``.
"""

from __future__ import annotations

import numpy as np

from riskfield.protocol import EsdfGrid, PerceptionFrame, RobotState, TrackedObjects
from riskfield.protocol.ade20k import CLASSES

GROUP_TINT = {"high": (230, 40, 40), "mid": (245, 150, 30), "low": (150, 150, 150)}

def label_palette(n: int = 65536) -> np.ndarray:
    """A deterministic, well-spread RGB colour per label (golden-ratio hues)."""
    i = np.arange(min(n, 65536))
    h = (i * 0.618033988749895) % 1.0
    s, v = 0.65, 0.95
    k = (np.stack([5 + h * 6, 3 + h * 6, 1 + h * 6], 1)) % 6
    rgb = v - v * s * np.clip(np.minimum(k, 4 - k), 0, 1)
    return (rgb * 255).astype(np.uint8)


def ade20k_classes() -> list[tuple[int, str, tuple[int, int, int]]]:
    """(class id, ADE20K name, colour) for every class: the pointmap's annotation context."""
    pal = label_palette(len(CLASSES))
    return [(i, name, tuple(int(c) for c in pal[i])) for i, name in enumerate(CLASSES)]


def slice_index(grid: EsdfGrid, z: float) -> int:
    if grid.distance.shape[2] == 1:
        return 0
    k = round((z - grid.origin[2]) / grid.voxel_size)
    return min(max(k, 0), grid.distance.shape[2] - 1)


def esdf_slice(grid: EsdfGrid, z: float = 0.1) -> tuple[np.ndarray, tuple[float, float, float]]:
    """The signed distance at height z as an (ny, nx) float32 grid-map image (row r ↔ y index
    ny − 1 − r, column i ↔ x index i: the top row is the highest y), and the map-frame
    position of its lower-left corner."""
    k = slice_index(grid, z)
    d = np.ascontiguousarray(np.asarray(grid.distance[:, :, k], dtype=np.float32).T[::-1])
    s = grid.voxel_size
    corner = (grid.origin[0] - s / 2, grid.origin[1] - s / 2, grid.origin[2] + k * s)
    return d, corner


def map_bounds(grid: EsdfGrid) -> tuple[np.ndarray, np.ndarray]:
    """(min corner, size) of the box the grid's cells cover, map frame."""
    s = grid.voxel_size
    lo = np.asarray(grid.origin, dtype=float) - s / 2
    return lo, np.asarray(grid.distance.shape, dtype=float) * s


def inside_voxels(grid: EsdfGrid) -> tuple[np.ndarray, np.ndarray]:
    """Centres (N, 3) of the voxels inside the inflated set and their risk-group tint (N, 3)."""
    idx = np.argwhere(np.asarray(grid.distance) < 0)
    centres = np.asarray(grid.origin, dtype=float) + idx * grid.voxel_size
    groups = np.asarray(grid.risk_group)[tuple(idx.T)] if len(idx) else np.zeros(0, np.uint8)
    table = np.array([(120, 120, 220)] + [GROUP_TINT.get(n, (120, 120, 220)) for n in grid.groups], np.uint8)
    return centres, table[np.minimum(groups, len(table) - 1)]


def pointmap_world(frame: PerceptionFrame, stride: int = 4, min_confidence: float = 0.0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """World-frame points (N, 3) and their ADE20K class ids (N,) from a camera-frame pointmap."""
    p = np.asarray(frame.pointmap()[::stride, ::stride], dtype=float).reshape(-1, 3)
    c = np.asarray(frame.confidence[::stride, ::stride]).reshape(-1)
    lab = np.asarray(frame.labels[::stride, ::stride]).reshape(-1)
    keep = (c > min_confidence) & (p[:, 2] > 0) & np.isfinite(p).all(axis=1)
    T = np.asarray(frame.T_WC, dtype=float)
    world = p[keep] @ T[:3, :3].T + T[:3, 3]
    return world, lab[keep].astype(np.uint16)


def footprint(radius: float, n: int = 32) -> np.ndarray:
    """The robot's outline in its own frame: a closed circle of ``radius`` and a heading tick
    along +x (drawn as a child of ``world/robot``, so it moves with the robot's transform)."""
    a = np.linspace(0, 2 * np.pi, n + 1)
    circle = np.column_stack([radius * np.cos(a), radius * np.sin(a), np.zeros(n + 1)])
    tick = np.array([[0.0, 0.0, 0.0], [radius, 0.0, 0.0]])
    return np.vstack([circle, tick])


def robot_pose(state: RobotState) -> np.ndarray:
    """``T_WR`` (4×4) from a state's position and xyzw quaternion."""
    x, y, z, w = (float(v) for v in state.orientation)
    n = np.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / n, y / n, z / n, w / n
    T = np.eye(4)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    T[:3, 3] = state.position
    return T


def camera_in_robot(T_WC: np.ndarray, T_WR: np.ndarray) -> np.ndarray:
    """``T_RC = T_WR⁻¹ · T_WC``: the camera's pose in the robot frame."""
    return np.linalg.solve(np.asarray(T_WR, dtype=float), np.asarray(T_WC, dtype=float))


def intrinsics_from_pointmap(points: np.ndarray) -> tuple[float, float, float, float] | None:
    """(fx, fy, cx, cy) of the pinhole that best explains a camera-frame pointmap.

    Pixel (u, v) holds a point (X, Y, Z) with ``u = fx·X/Z + cx`` and ``v = fy·Y/Z + cy``: two
    least-squares line fits over the valid pixels. None when fewer than 3 pixels are valid or
    the fit is degenerate (all points on one column or row)."""
    p = np.asarray(points, dtype=float)
    h, w = p.shape[:2]
    v, u = np.mgrid[0:h, 0:w]
    ok = np.isfinite(p).all(axis=2) & (p[..., 2] > 1e-6)
    if ok.sum() < 3:
        return None
    a, b = p[..., 0][ok] / p[..., 2][ok], p[..., 1][ok] / p[..., 2][ok]
    out = []
    for ray, pix in ((a, u[ok]), (b, v[ok])):
        if np.ptp(ray) < 1e-9:
            return None
        f, c = np.polyfit(ray, pix.astype(float), 1)
        out.append((f, c))
    (fx, cx), (fy, cy) = out
    if fx <= 0 or fy <= 0:
        return None
    return float(fx), float(fy), float(cx), float(cy)


class OnChange:
    """Passes a value only when it differs from the last one passed (text logs on change)."""

    def __init__(self) -> None:
        self._last: object = object()

    def __call__(self, value: object) -> bool:
        if value == self._last:
            return False
        self._last = value
        return True


def tracked_objects(m: TrackedObjects, groups: tuple[str, ...] = ("high", "mid", "low")
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """The tracked people and animals as centres (N, 3), radii (N,), velocities (N, 3), risk-group
    tints (N, 3) and labels ("person #3 1.20 m/s")."""
    n = len(m.objects)
    pos = np.array([o.position for o in m.objects], dtype=float).reshape(n, 3)
    vel = np.array([o.velocity for o in m.objects], dtype=float).reshape(n, 3)
    radii = np.array([o.radius for o in m.objects], dtype=float)
    names = [groups[o.risk_group - 1] if 0 < o.risk_group <= len(groups) else "" for o in m.objects]
    tint = np.array([GROUP_TINT.get(g, (120, 120, 220)) for g in names], np.uint8).reshape(n, 3)
    labels = [f"{CLASSES[o.label] if o.label < len(CLASSES) else o.label} #{o.id} {np.linalg.norm(v):.2f} m/s"
              for o, v in zip(m.objects, vel, strict=True)]
    return pos, radii, vel, tint, labels
