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

from ..runtime.jit import jit
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
        T = np.asarray(T_WC, np.float64)
        limits = np.array([self.min_confidence, self.min_depth, self.max_depth, self.truncation, floor_z, top_z])
        # copies: C-ordered and writable whatever the frame's arrays are, so one compiled signature serves
        return _mark_free(np.array(points[::s, ::s]), np.array(confidence[::s, ::s]),
                          np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), limits,
                          volume.voxel_size, volume.origin_index[:2].copy(), layer.seen_ms, now_ms)


@jit(error_model="numpy")
def _mark_free(points: np.ndarray, confidence: np.ndarray, R: np.ndarray, centre: np.ndarray, limits: np.ndarray,
               voxel_size: float, origin_index: np.ndarray, seen_ms: np.ndarray, now_ms: int) -> int:
    """Each ray of ``points`` (camera frame) whose confidence and range pass ``limits`` = (min
    confidence, min and max depth, truncation, floor z, top z) is sampled every half voxel from the
    camera up to ``truncation`` short of its point; a sample between floor z and top z marks its
    cell. Returns the cells marked.

    Compiled, sample by sample: the same sampling as whole arrays (rays × samples × 3, every sample
    of the longest ray for every ray) took 6.4 ms a frame in the mapping node, twice the TSDF and
    semantic integration together."""
    min_conf, min_depth, max_depth, truncation, floor_z, top_z = limits
    h = voxel_size * 0.5
    nx, ny = seen_ms.shape[0], seen_ms.shape[1]
    marked = np.zeros((nx, ny), np.bool_)
    n = 0
    for v in range(points.shape[0]):
        for u in range(points.shape[1]):
            px, py, pz = np.float64(points[v, u, 0]), np.float64(points[v, u, 1]), np.float64(points[v, u, 2])
            r = np.sqrt(px * px + py * py + pz * pz)
            if not (np.isfinite(r) and confidence[v, u] >= min_conf and min_depth <= r <= max_depth):
                continue
            free_len = r - truncation
            dx = (R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz) / r
            dy = (R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz) / r
            dz = (R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz) / r
            m = 0
            while m * h <= free_len:
                t = m * h
                m += 1
                z = centre[2] + dz * t
                if z < floor_z or z > top_z:
                    continue
                i = np.int64(np.floor((centre[0] + dx * t) / voxel_size + 0.5)) - origin_index[0]
                j = np.int64(np.floor((centre[1] + dy * t) / voxel_size + 0.5)) - origin_index[1]
                if 0 <= i < nx and 0 <= j < ny:
                    seen_ms[i, j, 0] = now_ms
                    if not marked[i, j]:
                        marked[i, j] = True
                        n += 1
    return n
