"""Semantic occupancy: surface support, obstacle label filtering, label → risk group, unknown space."""

from __future__ import annotations

import numpy as np

from riskfield.protocol import RiskConfig, ade20k
from riskfield.services.mapping.layers import NO_LABEL, SemanticLayer, TsdfLayer
from riskfield.services.mapping.occupancy import OccupancyRule, semantic_occupancy


def layers() -> tuple[TsdfLayer, SemanticLayer]:
    t, s = TsdfLayer((8, 1, 1), 0.15), SemanticLayer((8, 1, 1))
    t.weight[:, 0, 0] = [5, 5, 5, 5, 5, 0.2, 5, 0]
    t.tsdf[:, 0, 0] = [0.0, 0.01, -0.02, 0.03, 0.1, 0.0, 0.0, 0.15]
    names = ["person", "chair", "wall", "floor", "person", "person"]
    s.label[:6, 0, 0] = [ade20k.index(n) for n in names]
    s.label[6, 0, 0] = NO_LABEL
    return t, s


def test_groups_follow_the_risk_config_and_free_labels_are_dropped() -> None:
    risk = RiskConfig()
    t, s = layers()
    g = semantic_occupancy(t, s, risk.label_to_group(), OccupancyRule(min_weight=0.5, surface_band=0.0375))
    high, mid, low = (risk.group_id(n) for n in ("high", "mid", "low"))
    # person, chair, wall on the surface; floor is free; 4: off the surface; 5: too little weight;
    # 6: never labelled (no pixel saw a surface there); 7: unknown
    assert g[:, 0, 0].tolist() == [high, mid, low, 0, 0, 0, 0, 0]


def test_a_reloaded_config_moves_labels_between_groups() -> None:
    risk = RiskConfig(groups=[{"name": "pets", "labels": [ade20k.index("chair")], "margin": 0.3},
                              {"name": "rest", "labels": [], "margin": 0.0}], default_group="rest")
    t, s = layers()
    g = semantic_occupancy(t, s, risk.label_to_group(), OccupancyRule(0.5, 0.0375))
    assert g[:3, 0, 0].tolist() == [2, 1, 2]
    # default_group None: labels listed nowhere are left to the floor, the last (lowest) group, and
    # only the free surfaces (the floor) are free: the person and the wall stay obstacles
    only_chairs = RiskConfig(groups=[{"name": "c", "labels": [ade20k.index("chair")]}], default_group=None)
    only = semantic_occupancy(t, s, only_chairs.label_to_group(), OccupancyRule(0.5, 0.0375))
    assert only[:, 0, 0].tolist() == [1, 1, 1] + [0] * 5


def test_unknown_is_occupied_marks_never_observed_voxels() -> None:
    t, s = layers()
    g = semantic_occupancy(t, s, RiskConfig().label_to_group(), OccupancyRule(0.5, 0.0375, unknown_group=3))
    assert g[7, 0, 0] == 3
    assert g[5, 0, 0] == 0  # observed (weight 0.2 > 0) but not enough for a surface: not unknown


def column(tsdf: list[float], labels: list[str | None], weight: float = 5.0) -> tuple[TsdfLayer, SemanticLayer]:
    """One line of voxels along x; ``None`` = no label."""
    n = len(tsdf)
    t, s = TsdfLayer((n, 1, 1), 0.15), SemanticLayer((n, 1, 1))
    t.tsdf[:, 0, 0] = tsdf
    t.weight[:, 0, 0] = weight
    s.label[:, 0, 0] = [NO_LABEL if name is None else ade20k.index(name) for name in labels]
    return t, s


def test_the_observed_interior_takes_the_group_of_its_nearest_labelled_surface() -> None:
    risk = RiskConfig()
    high, mid = risk.group_id("high"), risk.group_id("mid")
    # free, person surface, inside ×3 (the last nearer the chair's back surface), chair surface, free
    t, s = column([0.1, 0.0, -0.05, -0.1, -0.1, -0.05, 0.0, 0.1],
                  [None, "person", None, None, None, None, "chair", None])
    g = semantic_occupancy(t, s, risk.label_to_group(), OccupancyRule(0.5, 0.0375))
    assert g[:, 0, 0].tolist() == [0, high, high, high, mid, mid, mid, 0]
    # the former hollow rule keeps only the surface
    shell = semantic_occupancy(t, s, risk.label_to_group(), OccupancyRule(0.5, 0.0375, interior="shell"))
    assert shell[:, 0, 0].tolist() == [0, high, 0, 0, 0, 0, mid, 0]


def test_under_a_free_surface_stays_free_and_ties_go_to_the_obstacle() -> None:
    risk = RiskConfig()
    # floor surface, then its underside, reached from both ends: each voxel takes the nearer
    # surface, so the floor's side stays free
    t, s = column([0.0, -0.05, -0.1, -0.1, -0.05, 0.0], ["floor", None, None, None, None, "person"])
    g = semantic_occupancy(t, s, risk.label_to_group(), OccupancyRule(0.5, 0.0375))
    assert g[:, 0, 0].tolist() == [0, 0, 0, 1, 1, 1]
    # the middle voxel is equally near both: it goes to the obstacle
    t, s = column([0.0, -0.05, -0.1, -0.05, 0.0], ["floor", None, None, None, "person"])
    g = semantic_occupancy(t, s, risk.label_to_group(), OccupancyRule(0.5, 0.0375))
    assert g[:, 0, 0].tolist() == [0, 0, 1, 1, 1]


def test_unlabelled_band_voxels_and_unreached_interior_stay_free() -> None:
    risk = RiskConfig()
    # a spurious crossing (in the band, no label) and an interior pocket no label reaches
    t, s = column([0.1, -0.02, 0.1, -0.1, -0.1, 0.1], [None] * 6)
    assert semantic_occupancy(t, s, risk.label_to_group(), OccupancyRule(0.5, 0.0375)).sum() == 0


def test_the_fill_runs_along_the_viewing_direction_only_into_never_observed_voxels() -> None:
    risk = RiskConfig()
    n = 12
    t, s = TsdfLayer((n, 3, 3), 0.15), SemanticLayer((n, 3, 3))
    # seen along +x: free, the surface at 2, observed interior 3..4, never observed from 5 on,
    # except voxel 9, seen free (another view past the object)
    t.tsdf[:5] = np.array([0.1, 0.05, 0.0, -0.05, -0.1])[:, None, None]
    t.weight[:5] = 5.0
    t.tsdf[9], t.weight[9] = 0.15, 5.0
    s.label[2] = ade20k.index("chair")
    t.view[3:5, ..., 0] = 127  # the rays that saw them behind the surface ran along +x
    lut = risk.label_to_group()
    mid = risk.group_id("mid")
    for steps, expect in ((0, [0, 0, mid, mid, mid] + [0] * 7), (3, [0, 0, mid, mid, mid, mid, mid, mid, 0, 0, 0, 0]),
                          (10, [0, 0] + [mid] * 7 + [0, 0, 0])):
        g = semantic_occupancy(t, s, lut, OccupancyRule(0.5, 0.0375, fill_steps=steps))
        assert g[:, 1, 1].tolist() == expect, (steps, g[:, 1, 1].tolist())
    # nothing is filled towards the camera (−x) nor without a viewing direction
    t.view[...] = 0
    assert semantic_occupancy(t, s, lut, OccupancyRule(0.5, 0.0375, fill_steps=10))[5:, 1, 1].sum() == 0
    # unknown_is_occupied still marks the never-observed voxels the fill did not claim
    g = semantic_occupancy(t, s, lut, OccupancyRule(0.5, 0.0375, unknown_group=3, fill_steps=10))
    assert g[5, 1, 1] == 3 and g[9, 1, 1] == 0
