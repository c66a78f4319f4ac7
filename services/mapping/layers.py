"""Per-voxel layers of the map, all on the same ``Volume`` grid (C order, index (i, j, k)).

* ``TsdfLayer``: truncated signed distance (m, + in front of the surface) and its weight
  (sum of observation confidences, capped). Weight 0 means never observed (unknown). ``view``
  holds, for voxels seen behind a surface, the direction (×127, int8) of the last ray that saw
  them so: where the never-observed space behind that surface lies. ``hit`` holds the time (ms on the
  mapper's clock, ``NEVER`` if none) a current frame last saw the voxel *at* a surface (in the
  truncation band or behind it): person/animal voxels not seen so for ``dynamic_persist_s`` decay.
* ``SemanticLayer``: the fused ADE20K label and its vote weight (the paper's eq. 7–8 state).
  ``NO_LABEL`` marks a voxel that never received a vote.
"""

from __future__ import annotations

import numpy as np

from ..runtime.jit import jit
from .volume import shift_array

NEVER = np.iinfo(np.int32).min // 2
"""``TsdfLayer.hit`` of a voxel no current frame has seen at a surface (far enough below any clock
value that ``now − NEVER`` does not overflow int64 arithmetic and exceeds every persistence)."""

NO_LABEL = 65535
"""Label of a voxel without votes; beyond ADE20K's 150 classes, mapped by the risk LUT like any label."""


class TsdfLayer:
    def __init__(self, shape: tuple[int, int, int], truncation: float):
        self.truncation = float(truncation)
        self.tsdf = np.full(shape, self.truncation, dtype=np.float32)
        self.weight = np.zeros(shape, dtype=np.float32)
        self.view = np.zeros((*shape, 3), dtype=np.int8)
        self.hit = np.full(shape, NEVER, dtype=np.int32)

    def shift(self, delta: np.ndarray) -> None:
        shift_array(self.tsdf, delta, self.truncation)
        shift_array(self.weight, delta, 0.0)
        shift_array(self.view, delta, 0)
        shift_array(self.hit, delta, NEVER)

    def clear(self) -> None:
        self.tsdf.fill(self.truncation)
        self.weight.fill(0.0)
        self.view.fill(0)
        self.hit.fill(NEVER)

    @property
    def observed(self) -> np.ndarray:
        return self.weight > 0


class SemanticLayer:
    def __init__(self, shape: tuple[int, int, int]):
        self.label = np.full(shape, NO_LABEL, dtype=np.uint16)
        self.vote = np.zeros(shape, dtype=np.float32)

    def shift(self, delta: np.ndarray) -> None:
        shift_array(self.label, delta, NO_LABEL)
        shift_array(self.vote, delta, 0.0)

    def clear(self) -> None:
        self.label.fill(NO_LABEL)
        self.vote.fill(0.0)


@jit
def overlay(base: tuple, top: tuple, out: tuple, min_weight: float, band: float) -> int:
    """Flat (C-order) layers, each (tsdf, weight, view, label, vote): ``out`` = ``top`` where it has
    seen a voxel (weight ≥ ``min_weight``) and ``base`` has not or they disagree on an obstacle
    (TSDF ≤ ``band``), else ``base`` (``PresentLayer.over``); one pass instead of a dozen whole-array
    operations. Returns the voxels taken from ``top``."""
    base_d, base_w, base_view, base_label, base_vote = base
    top_d, top_w, top_view, top_label, top_vote = top
    out_d, out_w, out_view, out_label, out_vote = out
    n = 0
    for f in range(base_d.size):
        use = False
        if top_w[f] >= min_weight:
            if base_w[f] < min_weight:
                use = True
            else:
                use = (top_d[f] <= band) != (base_d[f] <= band)
        if use:
            out_d[f], out_w[f], out_label[f], out_vote[f] = top_d[f], top_w[f], top_label[f], top_vote[f]
            for a in range(3):
                out_view[f, a] = top_view[f, a]
            n += 1
        else:
            out_d[f], out_w[f], out_label[f], out_vote[f] = base_d[f], base_w[f], base_label[f], base_vote[f]
            for a in range(3):
                out_view[f, a] = base_view[f, a]
    return n
