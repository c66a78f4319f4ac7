"""TSDF surface support + semantic labels → semantic occupancy (the paper's O and Ψ(O, S)).

A voxel is *occupied* when it supports the fused surface,

    weight ≥ min_weight,   |tsdf| ≤ surface_band,   and it holds a fused label,

and its obstacle *risk group* is the risk config's ``label_to_group()[label]`` of its fused
label. Labels outside the obstacle set (``free_labels``: floor, ceiling, …) map to group 0
and are dropped, exactly the filtering step of Algorithm 1. The label condition means some
pixel saw a surface in this very voxel (labels are voted in the same band): it removes the
spurious zero crossings a TSDF grows just behind object edges, where the negative band of
one surface averages with the free space seen past the edge.

With ``unknown_is_occupied`` every never-observed voxel (weight 0) is also an obstacle, of
the ``unknown_group``.
"""

from __future__ import annotations

import numpy as np

from .layers import NO_LABEL, SemanticLayer, TsdfLayer


def surface_support(tsdf: TsdfLayer, min_weight: float, surface_band: float) -> np.ndarray:
    """Boolean mask of the voxels on the fused surface."""
    return (tsdf.weight >= max(min_weight, 1e-12)) & (np.abs(tsdf.tsdf) <= surface_band)


def semantic_occupancy(tsdf: TsdfLayer, semantic: SemanticLayer, label_to_group: np.ndarray, min_weight: float,
                       surface_band: float, unknown_group: int = 0) -> np.ndarray:
    """Per-voxel obstacle group (uint8, 1-based risk group id, 0 = not an obstacle).

    ``unknown_group`` > 0 marks never-observed voxels as obstacles of that group.
    """
    occupied = surface_support(tsdf, min_weight, surface_band)
    occupied &= semantic.label != NO_LABEL
    groups = np.zeros(occupied.shape, dtype=np.uint8)
    groups[occupied] = label_to_group[semantic.label[occupied]]
    if unknown_group > 0:
        groups[tsdf.weight <= 0] = unknown_group
    return groups
