"""The floor seen free: where an evading robot may retreat (``EsdfGrid.observed_free``).

Free in the ESDF is not the same as seen free: space no camera ever looked at has no obstacle in
the occupancy either (``unknown_is_occupied`` off), and a robot that backs into it may meet a wall
its front camera never saw. This layer keeps, per floor cell of the 2-D slice, when a camera ray
last crossed the cell above the floor and below the top of the ESDF's height band without meeting
a surface (every ray of a frame, every ``observed_free_stride`` pixels, up to ``truncation`` short
of what it hit). A cell counts as observed free for ``observed_free_s`` after that, and only where
the occupancy holds no obstacle in its band now (someone who stepped in since is not free).

A ray over the floor at a height below the band still says the cell is free: an obstacle standing
on the floor there would have met it first. What hangs over the band (a table top) is the
occupancy's to say, and it does.
"""

from __future__ import annotations

import numpy as np

from .config import FloorParams
from .layers import NEVER
from .volume import Volume, shift_array


class FreeFloorLayer:
    """Per floor cell (x, y of the volume), the mapper's clock (ms) when a ray last saw it free."""

    def __init__(self, shape: tuple[int, int, int]):
        self.seen_ms = np.full((*shape[:2], 1), NEVER, np.int32)

    def shift(self, delta: np.ndarray) -> None:
        shift_array(self.seen_ms, np.array([delta[0], delta[1], 0]), NEVER)

    def clear(self) -> None:
        self.seen_ms[...] = NEVER

    def observed_free(self, now_ms: int, window_s: float, band_obstacle: np.ndarray) -> np.ndarray:
        """(nx, ny, 1) uint8: seen free within ``window_s`` of ``now_ms``, and no obstacle in the band now."""
        recent = (np.int64(now_ms) - self.seen_ms.astype(np.int64)) <= round(window_s * 1e3)
        return (recent & ~band_obstacle[..., None]).astype(np.uint8)


class FreeFloorIntegrator:
    """Camera rays → ``FreeFloorLayer`` (module doc)."""

    def __init__(self, params: FloorParams, truncation: float, min_confidence: float, min_depth: float,
                 max_depth: float):
        self.params = params
        self.truncation, self.min_confidence = truncation, min_confidence
        self.min_depth, self.max_depth = min_depth, max_depth

    def integrate(self, volume: Volume, layer: FreeFloorLayer, points: np.ndarray, confidence: np.ndarray,
                  T_WC: np.ndarray, floor_z: float, top_z: float, now_ms: int) -> int:
        """Mark the cells the frame's rays crossed between ``floor_z`` and ``top_z`` (world z);
        ``points`` (H, W, 3) in the camera frame. Returns the cells marked."""
        s = self.params.observed_free_stride
        pts = np.asarray(points, np.float64)[::s, ::s].reshape(-1, 3)
        conf = np.asarray(confidence)[::s, ::s].reshape(-1)
        rng = np.linalg.norm(pts, axis=1)
        ok = np.isfinite(rng) & (conf >= self.min_confidence) & (rng >= self.min_depth) & (rng <= self.max_depth)
        if not ok.any():
            return 0
        T = np.asarray(T_WC, np.float64)
        centre = T[:3, 3]
        ends = pts[ok] @ T[:3, :3].T + centre
        free_len = rng[ok] - self.truncation
        h = volume.voxel_size * 0.5
        steps = np.arange(0.0, float(free_len.max()) + h, h) if free_len.max() > 0 else np.zeros(0)
        if not steps.size:
            return 0
        dirs = (ends - centre) / rng[ok][:, None]
        keep = steps[None, :] <= free_len[:, None]  # (rays, samples)
        samples = centre + dirs[:, None, :] * steps[None, :, None]
        keep &= (samples[..., 2] >= floor_z) & (samples[..., 2] <= top_z)
        ij = volume.to_index(samples[keep])[:, :2]
        nx, ny = layer.seen_ms.shape[:2]
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        ij = ij[inside]
        layer.seen_ms[ij[:, 0], ij[:, 1], 0] = now_ms
        return len(np.unique(ij[:, 0] * ny + ij[:, 1]))
