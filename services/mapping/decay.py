"""The decay of people and animals: the mapper's stage that lets what moves by itself leave the map.

A voxel of a ``dynamic_labels`` class at or behind a surface that no current frame has seen so
(``TsdfLayer.hit``) for ``dynamic_persist_s`` is cleared; outside the places the object tracker
protects (``ObjectTracker.protected``: where people stand or are seen now), already after
``dynamic_moving_persist_s``. The weight of the rest is capped at ``dynamic_max_weight`` in the
running-mean layers, so the space a person leaves clears within a few frames. Furniture and walls
never decay. The mapper's module docstring ("The map shows the present") says why.

No I/O: the mapper hands it the layers, the volume and the last occupancy at each update.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskfield.protocol import ade20k

from .config import DynamicParams
from .layers import NEVER, NO_LABEL, SemanticLayer, TsdfLayer
from .volume import Volume

#: Frame time (ms) between two decays.
PERIOD_MS = 100


@dataclass
class DecayLayers:
    """One pair of layers the decay reads and clears; ``running_mean``: the weight cap applies (a
    keyframe's sums must stay exactly removable, so the keyframes' TSDF is capped only while it
    holds no keyframe)."""

    tsdf: TsdfLayer
    semantic: SemanticLayer
    running_mean: bool


class DynamicDecay:
    """People's and animals' voxels, forgotten when unseen (the module's docstring)."""

    def __init__(self, params: DynamicParams, surface_band: float, object_gate: float):
        self.params = params
        self.surface_band = surface_band
        self.object_gate = object_gate  # a protected footprint grows by the tracker's association gate
        self.dynamic = np.zeros(NO_LABEL + 1, bool)
        self.dynamic[[ade20k.index(name) for name in params.dynamic_labels]] = True
        #: where the tracker keeps people for T (``ObjectTracker.protected``); None: no tracker, T everywhere
        self.protected: list[tuple[np.ndarray, float]] | None = None
        self.decayed_voxels = 0
        self.forgotten_voxels = 0  # of those, walkers' voxels cleared after T_w
        self._last_ms = NEVER

    def decay(self, now_ms: int, layers: list[DecayLayers], volume: Volume | None,
              groups: np.ndarray | None, label_to_group: np.ndarray) -> int:
        """Clear the voxels unseen for T (or for T_w outside ``protected``) and cap the rest's weight,
        at most every :data:`PERIOD_MS` of frame time. ``groups``: the last occupancy, when it was
        made at the volume's present origin (it gives the unlabelled inside of a person its group).
        Returns the voxels cleared."""
        if now_ms - self._last_ms < PERIOD_MS:
            return 0
        self._last_ms = now_ms
        p = self.params
        oldest = now_ms - round(p.dynamic_persist_s * 1e3)
        gone = now_ms - round(p.dynamic_moving_persist_s * 1e3) if self.protected is not None else None
        keep = self._kept(volume) if gone is not None and self.protected else None
        moving = np.zeros(256, bool)
        moving[label_to_group[np.flatnonzero(self.dynamic)]] = True
        moving[0] = False
        n = forgotten = 0
        for layer in layers:
            k, f = self._forget(layer, oldest, gone, keep, groups, moving)
            n, forgotten = n + k, forgotten + f
        self.decayed_voxels += n
        self.forgotten_voxels += forgotten
        return n

    def _kept(self, volume: Volume | None) -> np.ndarray:
        """(nx, ny) columns inside the protected cylinders."""
        assert volume is not None and self.protected
        nx, ny, _ = volume.shape
        xy = volume.to_world(np.stack(np.meshgrid(np.arange(nx), np.arange(ny), [0], indexing="ij"), -1))[..., 0, :2]
        inside = np.zeros((nx, ny), bool)
        for centre, radius in self.protected:
            # The footprint grown by the association gate: the map shows a person a frame or two
            # late, so their leading edge not yet in the occupancy lies around it.
            inside |= np.hypot(xy[..., 0] - centre[0], xy[..., 1] - centre[1]) <= radius + self.object_gate
        return inside

    def _forget(self, layer: DecayLayers, oldest: int, gone: int | None, keep: np.ndarray | None,
                groups: np.ndarray | None, moving: np.ndarray) -> tuple[int, int]:
        """One pair of layers: (voxels cleared, of which for ``gone``). Free space is kept."""
        tsdf, sem = layer.tsdf, layer.semantic
        # Obstacle voxels first (a few % of the volume), then their labels and times: only what
        # makes an obstacle is cleared.
        flat_t, flat_w = tsdf.tsdf.reshape(-1), tsdf.weight.reshape(-1)
        cand = np.flatnonzero((flat_t <= self.surface_band) & (flat_w > 0))
        # A person's or animal's voxels: their labelled surface, and the unlabelled inside to which
        # the last occupancy gave their group (it is out of view when they stand close: above the
        # camera's view, it would outlive them, kept by a surface still in view).
        labels = sem.label.reshape(-1)[cand]
        body = self.dynamic[labels]
        if groups is not None:
            body |= (labels == NO_LABEL) & moving[groups.reshape(-1)[cand]]
        cand = cand[body]
        if layer.running_mean:
            flat_w[cand] = np.minimum(flat_w[cand], np.float32(self.params.dynamic_max_weight))
        hit = tsdf.hit.reshape(-1)[cand]
        forgotten = 0
        if gone is None:
            cand = cand[hit < oldest]
        else:
            away = hit < gone
            if keep is not None:
                away &= ~keep.reshape(-1)[cand // tsdf.tsdf.shape[2]]
            forgotten = int((away & (hit >= oldest)).sum())
            cand = cand[(hit < oldest) | away]
        stale = np.unravel_index(cand, tsdf.tsdf.shape)
        if cand.size:
            tsdf.tsdf[stale] = tsdf.truncation
            tsdf.weight[stale] = 0.0
            tsdf.view[stale] = 0
            tsdf.hit[stale] = NEVER
            sem.label[stale] = NO_LABEL
            sem.vote[stale] = 0.0
        return int(cand.size), forgotten
