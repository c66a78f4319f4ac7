"""Oracles of the 3-D ESDF: the same field by other means, for the tests to compare the mapper's
compiled, incremental path against.

``NumpyEsdf``: the 3-D field by the array-operation path (``EsdfIntegrator._field``, which the 2-D
slice and the ``dilate`` inflation run in production) instead of the compiled passes.
``EdtEsdf``: the compiled passes on the ``edt`` package's transforms instead of
``distance_transform``'s (deep interiors from one transform of the whole grid).
``FullEsdf``: every update a full recomputation (``EsdfIntegrator.compute``).
"""

from __future__ import annotations

import edt
import numpy as np

from riskfield.services.mapping.esdf_integrator import EsdfIntegrator


class NumpyEsdf(EsdfIntegrator):
    """The 3-D field by the array-operation path: the compiled passes' cross-check."""

    def _field3d(self, groups: np.ndarray, margins: np.ndarray,
                 counts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        return self._field(self._masks(groups, margins.shape[0] - 1), margins, shape=groups.shape, counts=counts)


class EdtEsdf(EsdfIntegrator):
    """The field with every distance transform by the ``edt`` package: the compiled transform's oracle."""

    def _edt(self, sites: np.ndarray) -> np.ndarray:
        free = np.ascontiguousarray(~np.asarray(sites, dtype=bool)).view(np.uint8)
        return edt.edt(free, anisotropy=(self.voxel_size,) * free.ndim, black_border=False)

    def _edt_of_label(self, labels: np.ndarray, label: int, equal: bool,
                      site_box: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        return self._edt((labels == label) == equal)

    def _edt_two_sided(self, union: np.ndarray) -> np.ndarray:
        """One multi-label transform: each voxel's distance to the nearest voxel of the other label."""
        labels = np.ascontiguousarray(union).view(np.uint8) + np.uint8(1)
        return edt.edt(labels, anisotropy=(self.voxel_size,) * union.ndim, black_border=False)

    def _deep_depth(self, groups: np.ndarray, depth: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                    occupied: tuple[np.ndarray, np.ndarray]) -> None:
        deep = depth < 0
        depth[deep] = self._edt_of_label(groups, 0, equal=True)[deep]  # to the nearest free voxel


class FullEsdf(EsdfIntegrator):
    """Every update recomputes the whole grid: the incremental update's oracle."""

    def update(self, groups: np.ndarray, margins: np.ndarray, previous_groups: np.ndarray,
               previous: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, int]:
        dist, grp = self.compute(groups, margins)
        return dist, grp, groups.size
