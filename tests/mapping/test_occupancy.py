"""Semantic occupancy: surface support, obstacle label filtering, label → risk group, unknown space."""

from __future__ import annotations

from riskfield.protocol import RiskConfig, ade20k
from riskfield.services.mapping.layers import NO_LABEL, SemanticLayer, TsdfLayer
from riskfield.services.mapping.occupancy import semantic_occupancy


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
    g = semantic_occupancy(t, s, risk.label_to_group(), min_weight=0.5, surface_band=0.0375)
    high, mid, low = (risk.group_id(n) for n in ("high", "mid", "low"))
    # person, chair, wall on the surface; floor is free; 4: off the surface; 5: too little weight;
    # 6: never labelled (no pixel saw a surface there); 7: unknown
    assert g[:, 0, 0].tolist() == [high, mid, low, 0, 0, 0, 0, 0]


def test_a_reloaded_config_moves_labels_between_groups() -> None:
    risk = RiskConfig(groups=[{"name": "pets", "labels": [ade20k.index("chair")], "margin": 0.3},
                              {"name": "rest", "labels": [], "margin": 0.0}], default_group="rest")
    t, s = layers()
    g = semantic_occupancy(t, s, risk.label_to_group(), 0.5, 0.0375)
    assert g[:3, 0, 0].tolist() == [2, 1, 2]
    # default_group None: labels listed nowhere are free
    only_chairs = RiskConfig(groups=[{"name": "c", "labels": [ade20k.index("chair")]}], default_group=None)
    assert semantic_occupancy(t, s, only_chairs.label_to_group(), 0.5, 0.0375)[:, 0, 0].tolist() == [0, 1] + [0] * 6


def test_unknown_is_occupied_marks_never_observed_voxels() -> None:
    t, s = layers()
    g = semantic_occupancy(t, s, RiskConfig().label_to_group(), 0.5, 0.0375, unknown_group=3)
    assert g[7, 0, 0] == 3
    assert g[5, 0, 0] == 0  # observed (weight 0.2 > 0) but not enough for a surface: not unknown
