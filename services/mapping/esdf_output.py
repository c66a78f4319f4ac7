"""The ESDF output stage: a semantic occupancy → the grids mapping publishes, and the field its
queries read.

    build(groups, ...)   per ``EsdfParams.output``: the 2-D slice of the height band (with the floor
                         observed free) for ``map/esdf``, and/or the 3-D grid, updated incrementally
                         from the last one while the volume and the margins stay (``EsdfIntegrator``)
    query(points)        distance, gradient and risk group of the last grid built (``fields.answer_query``)

It keeps what the next output needs of this one (the last 3-D grid, the field) and nothing of the
layers, so the ``Mapper`` hands it an occupancy and reads back a ``MapUpdate``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from riskfield.protocol import EsdfGrid, Header

from ..fields import EsdfField, FieldSample, answer_query, unknown_sample
from .config import EsdfParams
from .esdf_integrator import EsdfIntegrator
from .volume import Volume


@dataclass
class MapUpdate:
    """The grids of one ESDF update: the 2-D slice and/or the 3-D grid, per ``output``."""

    slice2d: EsdfGrid | None = None
    grid3d: EsdfGrid | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)
    occupancy: np.ndarray | None = None
    """The semantic occupancy the grids were built from (per-voxel risk group; the tracker's input)."""

    @property
    def primary(self) -> EsdfGrid:
        """What goes on ``map/esdf``: the slice when one is built, else the 3-D grid."""
        grid = self.slice2d if self.slice2d is not None else self.grid3d
        assert grid is not None
        return grid


class EsdfOutput:
    """Occupancy → the published ESDF grids and the queried field (module doc)."""

    def __init__(self, params: EsdfParams, voxel_size: float, unknown_is_occupied: bool):
        self.params = params
        self.unknown_is_occupied = unknown_is_occupied
        self.integrator = EsdfIntegrator(params, voxel_size)
        self.field: EsdfField | None = None
        self._last3d: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # groups, distance, risk group

    def forget(self) -> None:
        """New margins: the next 3-D grid is computed whole, not from the last one."""
        self._last3d = None

    def shift(self, delta: np.ndarray) -> None:
        """The volume moved by ``delta`` voxels."""
        self.integrator.shift(delta)
        self._last3d = None

    def band_indices(self, volume: Volume, base_z: float) -> tuple[int, int, float]:
        """z-voxel range [k_lo, k_hi) whose centres lie in the height band above ``base_z`` (the
        robot base), and the slice's z."""
        lo, hi = base_z + self.params.band[0], base_z + self.params.band[1]
        z0, v = float(volume.origin[2]), volume.voxel_size
        k_lo = math.ceil((lo - z0) / v - 1e-9)
        k_hi = math.floor((hi - z0) / v + 1e-9) + 1
        return k_lo, k_hi, 0.5 * (lo + hi)

    def build(self, groups: np.ndarray, volume: Volume, header: Header, margins: np.ndarray,
              group_names: list[str], base_z: float,
              observed_free: Callable[[np.ndarray], np.ndarray] | None) -> MapUpdate:
        """The grids of the occupancy ``groups`` (per-voxel risk group, 0: free) on ``volume``;
        ``observed_free`` maps the slice's obstacle cells to the floor observed free beside them
        (None: the slice carries none). The primary grid becomes the queried field."""
        t1 = time.perf_counter()
        out = MapUpdate(occupancy=groups)
        common = dict(voxel_size=volume.voxel_size, groups=group_names, max_distance=self.params.max_distance,
                      unknown_is_occupied=self.unknown_is_occupied)
        if self.params.output in ("2d", "both"):
            k_lo, k_hi, z = self.band_indices(volume, base_z)
            dist, grp = self.integrator.compute_slice(groups, k_lo, k_hi, margins)
            origin = volume.origin.copy()
            origin[2] = z
            free = None
            if observed_free is not None:
                free = observed_free((groups[:, :, max(k_lo, 0):max(k_hi, 0)] > 0).any(axis=2))
            out.slice2d = EsdfGrid(header=header.model_copy(), origin=tuple(origin.tolist()), distance=dist,
                                   risk_group=grp, observed_free=free, **common)
            t2 = time.perf_counter()
            out.timings_ms["esdf2d"] = (t2 - t1) * 1e3
            t1 = t2
        if self.params.output in ("3d", "both"):
            dist, grp = self._grid3d(groups, margins)
            out.grid3d = EsdfGrid(header=header.model_copy(), origin=tuple(volume.origin.tolist()),
                                  distance=dist, risk_group=grp, **common)
            out.timings_ms["esdf3d"] = (time.perf_counter() - t1) * 1e3
        self.field = EsdfField.from_grid(out.primary)
        return out

    def _grid3d(self, groups: np.ndarray, margins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The 3-D field, incrementally from the last one when the volume and margins are unchanged."""
        last = self._last3d
        if last is not None and last[0].shape == groups.shape:
            dist, grp, _ = self.integrator.update(groups, margins, last[0], (last[1], last[2]))
        else:
            dist, grp = self.integrator.compute(groups, margins)
        self._last3d = (groups, dist, grp)
        return dist, grp

    def query(self, points: np.ndarray) -> FieldSample:
        """Distance, gradient, risk group (and in-map flag, ``inside``) of the last field at world
        points: the filter's field and in-map rule (``fields.answer_query``); before any, unknown."""
        if self.field is None:
            n = np.asarray(points, dtype=np.float64).reshape(-1, 3).shape[0]
            return unknown_sample(n, self.params.max_distance, self.unknown_is_occupied)
        return answer_query(self.field, points)
