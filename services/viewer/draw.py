"""Pure conversions from riskfield messages to things one can draw (no Rerun import here).

Colours: the ESDF slice is shown free-space green → yellow near obstacles → black inside the
inflated set, tinted by the nearest obstacle's risk group (red high, orange mid, grey low);
pointmap points carry a fixed colour per ADE20K class.
"""

from __future__ import annotations

import numpy as np

from riskfield.protocol import EsdfGrid, PerceptionFrame, RobotState

GROUP_TINT = {"high": (230, 40, 40), "mid": (245, 150, 30), "low": (150, 150, 150)}


def label_palette(n: int = 65536) -> np.ndarray:
    """A deterministic, well-spread RGB colour per label (golden-ratio hues)."""
    i = np.arange(min(n, 65536))
    h = (i * 0.618033988749895) % 1.0
    s, v = 0.65, 0.95
    k = (np.stack([5 + h * 6, 3 + h * 6, 1 + h * 6], 1)) % 6
    rgb = v - v * s * np.clip(np.minimum(k, 4 - k), 0, 1)
    return (rgb * 255).astype(np.uint8)


_PALETTE = label_palette(256)


def slice_index(grid: EsdfGrid, z: float) -> int:
    if grid.distance.shape[2] == 1:
        return 0
    k = round((z - grid.origin[2]) / grid.voxel_size)
    return min(max(k, 0), grid.distance.shape[2] - 1)


def esdf_slice_rgb(grid: EsdfGrid, z: float = 0.1) -> np.ndarray:
    """An (ny, nx, 3) uint8 image of the signed distance at height z; row 0 is the lowest y."""
    k = slice_index(grid, z)
    d = np.asarray(grid.distance[:, :, k], dtype=float)
    g = np.asarray(grid.risk_group[:, :, k])
    t = np.clip(d / max(grid.max_distance, 1e-6), 0.0, 1.0)[..., None]
    free = (1 - t) * np.array([250, 220, 60]) + t * np.array([40, 170, 80])
    tint = np.zeros((*d.shape, 3))
    for gid, name in enumerate(grid.groups, start=1):
        tint[g == gid] = GROUP_TINT.get(name, (120, 120, 220))
    near = np.exp(-np.maximum(d, 0.0) / 0.3)[..., None] * (g > 0)[..., None]
    rgb = free * (1 - 0.6 * near) + tint * 0.6 * near
    rgb[d < 0] = np.array([20, 20, 20])
    return np.ascontiguousarray(np.transpose(rgb, (1, 0, 2)).astype(np.uint8))


def pointmap_world(frame: PerceptionFrame, stride: int = 4, min_confidence: float = 0.0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """World-frame points (N, 3) and their label colours (N, 3) from a camera-frame pointmap."""
    p = np.asarray(frame.points[::stride, ::stride], dtype=float).reshape(-1, 3)
    c = np.asarray(frame.confidence[::stride, ::stride]).reshape(-1)
    lab = np.asarray(frame.labels[::stride, ::stride]).reshape(-1)
    keep = (c > min_confidence) & (p[:, 2] > 0)
    T = np.asarray(frame.T_WC, dtype=float)
    world = p[keep] @ T[:3, :3].T + T[:3, 3]
    return world, _PALETTE[lab[keep] % 256]


def footprint(state: RobotState, radius: float, n: int = 32) -> np.ndarray:
    """A closed circle of the robot's radius around its position, plus a heading tick."""
    a = np.linspace(0, 2 * np.pi, n + 1)
    x, y, z = state.position
    circle = np.column_stack([x + radius * np.cos(a), y + radius * np.sin(a), np.full(n + 1, z)])
    yaw = state.yaw
    tick = np.array([[x, y, z], [x + radius * np.cos(yaw), y + radius * np.sin(yaw), z]])
    return np.vstack([circle, tick])
