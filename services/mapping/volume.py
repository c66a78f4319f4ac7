"""The rolling local volume: a regular voxel grid that follows the robot.

Voxel centres lie on the global lattice ``voxel_size · k`` (k integer), so a shift moves the
grid by whole voxels and the overlapping data is kept exactly. The grid is identified by the
integer lattice index of its voxel (0, 0, 0); its world origin (the *centre* of voxel
(0, 0, 0), the ``EsdfGrid`` convention) is ``voxel_size · origin_index``. Voxel (i, j, k)
covers the cube of side ``voxel_size`` centred on ``origin + voxel_size · (i, j, k)``.
"""

from __future__ import annotations

import numpy as np


class Volume:
    """Geometry of the rolling grid: shape, voxel size, lattice origin, world ↔ index."""

    def __init__(self, voxel_size: float, shape: tuple[int, int, int], origin_index: tuple[int, int, int] = (0, 0, 0)):
        if voxel_size <= 0:
            raise ValueError("voxel_size must be positive")
        if len(shape) != 3 or min(shape) < 1:
            raise ValueError(f"shape {shape} must be three positive counts")
        self.voxel_size = float(voxel_size)
        self.shape = tuple(int(n) for n in shape)
        self.origin_index = np.asarray(origin_index, dtype=np.int64)

    @classmethod
    def centred(cls, voxel_size: float, shape: tuple[int, int, int], centre: np.ndarray) -> Volume:
        vol = cls(voxel_size, shape)
        vol.origin_index = vol.origin_index_for(centre)
        return vol

    @property
    def origin(self) -> np.ndarray:
        """World position (m) of the centre of voxel (0, 0, 0)."""
        return self.origin_index * self.voxel_size

    @property
    def centre(self) -> np.ndarray:
        """World position of the middle of the grid."""
        return self.origin + 0.5 * self.voxel_size * (np.asarray(self.shape) - 1)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def origin_index_for(self, centre: np.ndarray) -> np.ndarray:
        """Lattice index of voxel (0,0,0) for a grid whose middle voxel is nearest ``centre``."""
        return self.lattice_index(centre) - np.asarray(self.shape, dtype=np.int64) // 2

    def lattice_index(self, points: np.ndarray) -> np.ndarray:
        """Nearest lattice index of world points, ties rounded up (np.round's ties-to-even would
        put a point halfway between voxel centres in another voxel than ``to_index`` does)."""
        return np.floor(np.asarray(points, dtype=np.float64) / self.voxel_size + 0.5).astype(np.int64)

    # -- world ↔ index ----------------------------------------------------------------------
    def to_index(self, points: np.ndarray) -> np.ndarray:
        """Integer voxel index (rounded) of world points (…×3); may lie outside the grid."""
        return self.lattice_index(points) - self.origin_index

    def to_continuous(self, points: np.ndarray) -> np.ndarray:
        """Fractional index: voxel centres sit at integers."""
        return (np.asarray(points, dtype=np.float64) - self.origin) / self.voxel_size

    def to_world(self, index: np.ndarray) -> np.ndarray:
        """World position of voxel centres (index may be fractional)."""
        return self.origin + np.asarray(index, dtype=np.float64) * self.voxel_size

    def contains_index(self, index: np.ndarray) -> np.ndarray:
        idx = np.asarray(index)
        return np.all((idx >= 0) & (idx < np.asarray(self.shape)), axis=-1)

    def centres(self) -> np.ndarray:
        """World positions of every voxel centre, shape (nx, ny, nz, 3) (for tests and tools)."""
        idx = np.indices(self.shape, dtype=np.float64).transpose(1, 2, 3, 0)
        return self.to_world(idx)

    # -- rolling ------------------------------------------------------------------------------
    def shift_to(self, new_origin_index: np.ndarray) -> np.ndarray:
        """Move the grid; returns the shift in voxels (new − old) the layers must apply."""
        new = np.asarray(new_origin_index, dtype=np.int64)
        delta = new - self.origin_index
        self.origin_index = new
        return delta


def shift_array(arr: np.ndarray, delta: np.ndarray, fill: float | int) -> None:
    """Move ``arr`` in place so that new[i] = old[i + delta]; voxels without overlap get ``fill``.

    The grid moved by ``delta`` voxels, so the voxel that now has index i used to have i + delta.
    """
    d = [int(x) for x in delta]
    if not any(d):
        return
    shape = arr.shape[:3]
    if any(abs(di) >= n for di, n in zip(d, shape, strict=True)):
        arr[...] = fill
        return
    dst, src = [], []
    for di, n in zip(d, shape, strict=True):
        if di >= 0:
            dst.append(slice(0, n - di))
            src.append(slice(di, n))
        else:
            dst.append(slice(-di, n))
            src.append(slice(0, n + di))
    arr[tuple(dst)] = arr[tuple(src)].copy()
    # Clear the slabs that came into view: everything outside the copied block.
    for axis, di in enumerate(d):
        if di == 0:
            continue
        n = shape[axis]
        sl = [slice(None)] * arr.ndim
        sl[axis] = slice(n - di, n) if di > 0 else slice(0, -di)
        arr[tuple(sl)] = fill
