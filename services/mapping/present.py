"""The present layer of the keyframe protocol: the mapper's stage that shows the camera's present view.

Under the keyframe protocol the keyframes' contributions stay exact and removable in the mapper's
TSDF, and every current frame is *also* integrated here: a running mean capped at ``max_weight``,
i.e. the last few frames. Where the two disagree on whether a voxel is an obstacle (a person who
came or left), or only this layer has seen it, the occupancy reads this layer; elsewhere the
keyframes' exact, re-posable map (:meth:`PresentLayer.over`). A ``keyframe_update`` that re-poses
the world clears it (:meth:`PresentLayer.clear`). The mapper's module docstring ("The map shows
the present") says why.

No I/O: the mapper integrates into :meth:`PresentLayer.layers` with its own integrators.
"""

from __future__ import annotations

import numpy as np

from .layers import SemanticLayer, TsdfLayer, overlay


class PresentLayer:
    """The last few current frames, and where they overrule the keyframes (the module's docstring)."""

    def __init__(self, shape: tuple[int, int, int], truncation: float, min_weight: float, surface_band: float):
        self.shape, self.truncation = shape, truncation
        self.min_weight = max(min_weight, 1e-12)  # observed: weight at least this
        self.surface_band = surface_band  # an obstacle: TSDF at most this
        self.tsdf: TsdfLayer | None = None  # made on the first current frame
        self.semantic: SemanticLayer | None = None
        self.overlaid = 0  # voxels this layer decided in the last composite
        self.clears = 0
        self._composite: tuple[TsdfLayer, SemanticLayer] | None = None

    def layers(self) -> tuple[TsdfLayer, SemanticLayer]:
        """The layers a current frame integrates into (made at the first)."""
        if self.tsdf is None or self.semantic is None:
            self.tsdf, self.semantic = TsdfLayer(self.shape, self.truncation), SemanticLayer(self.shape)
        return self.tsdf, self.semantic

    def shift(self, delta: np.ndarray) -> None:
        """The volume moved by ``delta`` voxels."""
        if self.tsdf is not None and self.semantic is not None:
            self.tsdf.shift(delta)
            self.semantic.shift(delta)

    def clear(self) -> bool:
        """The keyframes were re-posed: this layer was built in the old frame of reference. True if
        there was one to clear."""
        if self.tsdf is None or self.semantic is None:
            return False
        self.tsdf.clear()
        self.semantic.clear()
        self.clears += 1
        return True

    def over(self, tsdf: TsdfLayer, semantic: SemanticLayer) -> tuple[TsdfLayer, SemanticLayer]:
        """What the occupancy reads: the keyframes' ``tsdf`` and ``semantic``, overlaid by this layer
        where it has observed a voxel (weight ≥ ``min_weight``) and they have not, or they disagree
        on whether it is an obstacle (surface band or behind it). Where both agree the keyframes'
        exact, re-posable map stands, so a correction's result does not depend on the last few
        frames. Without a present layer: the keyframes' layers themselves."""
        p, ps = self.tsdf, self.semantic
        if p is None or ps is None:
            return tsdf, semantic
        if self._composite is None:
            self._composite = (TsdfLayer(self.shape, self.truncation), SemanticLayer(self.shape))
        ct, cs = self._composite
        n = tsdf.tsdf.size

        def flat(d: TsdfLayer, s: SemanticLayer) -> tuple[np.ndarray, ...]:
            return d.tsdf.reshape(n), d.weight.reshape(n), d.view.reshape(n, 3), s.label.reshape(n), s.vote.reshape(n)

        self.overlaid = overlay(flat(tsdf, semantic), flat(p, ps), flat(ct, cs), self.min_weight, self.surface_band)
        return ct, cs
