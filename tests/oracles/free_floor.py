"""The floor seen free by whole arrays (rays × samples), as a test oracle of the mapper's compiled
``free_floor._mark_free``: the same rays, sampled every half voxel up to ``truncation`` short of
their points, the samples between the floor and the top of the band marking their cells."""

from __future__ import annotations

import numpy as np


def mark_free_by_arrays(points: np.ndarray, confidence: np.ndarray, T_WC: np.ndarray, limits: np.ndarray,
                        voxel_size: float, origin_index: np.ndarray, seen_ms: np.ndarray, now_ms: int) -> int:
    """``_mark_free`` on the same arguments (``T_WC`` whole): writes ``seen_ms``, returns the cells marked."""
    min_conf, min_depth, max_depth, truncation, floor_z, top_z = (float(x) for x in limits)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    conf = np.asarray(confidence).reshape(-1)
    rng = np.sqrt(pts[:, 0] * pts[:, 0] + pts[:, 1] * pts[:, 1] + pts[:, 2] * pts[:, 2])
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(rng) & (conf >= min_conf) & (rng >= min_depth) & (rng <= max_depth)
    if not ok.any():
        return 0
    R, centre = np.asarray(T_WC, np.float64)[:3, :3], np.asarray(T_WC, np.float64)[:3, 3]
    p, r = pts[ok], rng[ok]
    dirs = np.stack([(R[a, 0] * p[:, 0] + R[a, 1] * p[:, 1] + R[a, 2] * p[:, 2]) / r for a in range(3)], axis=1)
    free_len = r - truncation
    h = voxel_size * 0.5
    if free_len.max() < 0:
        return 0
    steps = np.arange(int(free_len.max() / h) + 2) * h
    keep = steps[None, :] <= free_len[:, None]
    samples = centre + dirs[:, None, :] * steps[None, :, None]
    keep &= (samples[..., 2] >= floor_z) & (samples[..., 2] <= top_z)
    ij = np.floor(samples[keep][:, :2] / voxel_size + 0.5).astype(np.int64) - origin_index
    nx, ny = seen_ms.shape[:2]
    ij = ij[(ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)]
    seen_ms[ij[:, 0], ij[:, 1], 0] = now_ms
    return len(np.unique(ij[:, 0] * ny + ij[:, 1]))
