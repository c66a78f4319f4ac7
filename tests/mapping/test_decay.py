"""The decay stage (``services/mapping/decay.py``) on its own: which voxels leave, when, and where
the tracker protects them."""

from __future__ import annotations

import numpy as np

from riskfield.protocol import ade20k
from riskfield.services.mapping.config import DynamicParams
from riskfield.services.mapping.decay import DecayLayers, DynamicDecay
from riskfield.services.mapping.layers import NEVER, NO_LABEL, SemanticLayer, TsdfLayer
from riskfield.services.mapping.volume import Volume

SHAPE = (20, 20, 2)
VOXEL = 0.1
PERSON, WALL = ade20k.index("person"), ade20k.index("wall")
T_MS, TW_MS = 3000, 500  # dynamic_persist_s, dynamic_moving_persist_s


def layers() -> tuple[TsdfLayer, SemanticLayer]:
    return TsdfLayer(SHAPE, 0.15), SemanticLayer(SHAPE)


def surface(tsdf: TsdfLayer, sem: SemanticLayer, at: tuple[int, int, int], label: int, hit_ms: int,
            weight: float = 20.0) -> None:
    tsdf.tsdf[at] = 0.0
    tsdf.weight[at] = weight
    tsdf.hit[at] = hit_ms
    sem.label[at] = label
    sem.vote[at] = 1.0


def stage() -> DynamicDecay:
    return DynamicDecay(DynamicParams(dynamic_persist_s=T_MS / 1e3, dynamic_moving_persist_s=TW_MS / 1e3,
                                      dynamic_max_weight=5.0), surface_band=0.05, object_gate=0.0)


def label_to_group() -> np.ndarray:
    table = np.zeros(NO_LABEL + 1, np.uint8)
    table[PERSON], table[WALL] = 1, 3
    return table


def test_people_unseen_for_t_leave_and_walls_stay():
    tsdf, sem = layers()
    surface(tsdf, sem, (2, 2, 0), PERSON, hit_ms=0)  # unseen for T + 1 ms at the decay below
    surface(tsdf, sem, (4, 4, 0), PERSON, hit_ms=2)  # seen 1 ms within T
    surface(tsdf, sem, (6, 6, 0), WALL, hit_ms=0)
    d = stage()
    now = T_MS + 1
    assert d.decay(now, [DecayLayers(tsdf, sem, running_mean=False)], None, None, label_to_group()) == 1
    assert tsdf.weight[2, 2, 0] == 0 and sem.label[2, 2, 0] == NO_LABEL and tsdf.hit[2, 2, 0] == NEVER
    assert tsdf.weight[4, 4, 0] == 20 and sem.label[4, 4, 0] == PERSON  # not capped: the keyframes' sums
    assert tsdf.weight[6, 6, 0] == 20 and sem.label[6, 6, 0] == WALL
    assert (d.decayed_voxels, d.forgotten_voxels) == (1, 0)


def test_a_running_mean_caps_the_weight_of_what_moves_and_decays_at_most_every_period():
    tsdf, sem = layers()
    surface(tsdf, sem, (3, 3, 0), PERSON, hit_ms=1000)
    surface(tsdf, sem, (5, 5, 0), WALL, hit_ms=1000)
    d = stage()
    assert d.decay(1000, [DecayLayers(tsdf, sem, running_mean=True)], None, None, label_to_group()) == 0
    assert tsdf.weight[3, 3, 0] == 5.0 and tsdf.weight[5, 5, 0] == 20.0
    tsdf.weight[3, 3, 0] = 20.0
    d.decay(1099, [DecayLayers(tsdf, sem, running_mean=True)], None, None, label_to_group())
    assert tsdf.weight[3, 3, 0] == 20.0  # within the period: nothing ran


def test_outside_the_protected_places_a_walker_leaves_after_t_w():
    tsdf, sem = layers()
    vol = Volume(VOXEL, SHAPE)
    surface(tsdf, sem, (2, 2, 0), PERSON, hit_ms=1000)  # at (0.2, 0.2): protected below
    surface(tsdf, sem, (15, 15, 0), PERSON, hit_ms=1000)  # at (1.5, 1.5): not
    unlabelled = (15, 16, 0)
    surface(tsdf, sem, unlabelled, NO_LABEL, hit_ms=1000)  # a person's inside, by the last occupancy's group
    groups = np.zeros(SHAPE, np.uint8)
    groups[unlabelled] = 1
    d = stage()
    d.protected = [(np.array([0.2, 0.2]), 0.15)]
    n = d.decay(1000 + TW_MS + 1, [DecayLayers(tsdf, sem, running_mean=False)], vol, groups, label_to_group())
    assert n == 2 and d.forgotten_voxels == 2
    assert tsdf.weight[2, 2, 0] > 0 and tsdf.weight[15, 15, 0] == 0 and tsdf.weight[unlabelled] == 0
    # Without a tracker (protected None) the same voxels wait for T.
    tsdf2, sem2 = layers()
    surface(tsdf2, sem2, (15, 15, 0), PERSON, hit_ms=1000)
    assert stage().decay(1000 + TW_MS + 1, [DecayLayers(tsdf2, sem2, False)], vol, None, label_to_group()) == 0
