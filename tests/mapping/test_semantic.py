"""The paper's label vote rule (eq. 7–8) on hand-made sequences, scalar and through the integrator."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.layers import NO_LABEL, SemanticLayer
from riskfield.services.mapping.semantic_integrator import SemanticIntegrator, vote
from riskfield.services.mapping.volume import Volume


def run(seq: list[tuple[int, float]], label: int = NO_LABEL, weight: float = 0.0) -> tuple[int, float]:
    for y, q in seq:
        label, weight = vote(label, weight, y, q)
    return int(label), float(weight)


def test_first_observation_sets_the_label() -> None:
    assert run([(7, 0.8)]) == (7, pytest.approx(0.8))


def test_agreement_adds_disagreement_subtracts() -> None:
    assert run([(7, 1.0), (7, 0.5)]) == (7, pytest.approx(1.5))
    assert run([(7, 1.0), (3, 0.4)]) == (7, pytest.approx(0.6))


def test_label_replaced_only_when_the_weight_goes_negative() -> None:
    # w: 1.0 → 0.0 (exactly zero: not negative, label kept) → −0.5 → replaced by 3 with the surplus 0.5
    assert run([(7, 1.0), (3, 1.0)]) == (7, pytest.approx(0.0))
    assert run([(7, 1.0), (3, 1.0), (3, 0.5)]) == (3, pytest.approx(0.5))
    # a long history survives a burst of noise
    assert run([(7, 1.0)] * 5 + [(3, 1.0), (4, 1.0), (3, 1.0)]) == (7, pytest.approx(2.0))


@given(st.lists(st.tuples(st.integers(0, 3), st.floats(0.01, 5.0)), min_size=1, max_size=40))
def test_weight_stays_non_negative_and_equals_a_replay(seq: list[tuple[int, float]]) -> None:
    label, w = NO_LABEL, 0.0
    for y, q in seq:
        new_label, new_w = vote(label, w, y, q)
        # reference: the rule written out
        if y == label:
            ref = (label, w + q)
        elif w - q < 0:
            ref = (y, q - w)
        else:
            ref = (label, w - q)
        assert int(new_label) == ref[0] and new_w == pytest.approx(ref[1])
        assert new_w >= 0
        label, w = new_label, new_w


def test_integrator_votes_the_voxel_a_pixel_sees() -> None:
    cfg = MapperConfig(pixel_stride=1, min_confidence=0.0)
    vol = Volume.centred(0.05, (21, 21, 21), np.zeros(3))
    layer = SemanticLayer(vol.shape)
    integ = SemanticIntegrator(cfg, cfg.surface_band)
    T = np.eye(4)  # camera at the origin looking along +z
    pts = np.array([[[0.0, 0.0, 0.3]]], dtype=np.float32)
    target = tuple(vol.to_index(np.array([0.0, 0.0, 0.3])))

    def obs(label: int, q: float) -> None:
        integ.integrate(vol, layer, pts, np.array([[q]], np.float32), np.array([[label]], np.uint16), T)

    obs(12, 1.0)
    obs(12, 1.0)
    assert layer.label[target] == 12 and layer.vote[target] == pytest.approx(2.0)
    obs(5, 1.5)
    assert layer.label[target] == 12 and layer.vote[target] == pytest.approx(0.5)
    obs(5, 1.0)
    assert layer.label[target] == 5 and layer.vote[target] == pytest.approx(0.5)
    # voxels far in front of the point are not voted (free space carries no label)
    assert layer.label[tuple(vol.to_index(np.array([0.0, 0.0, 0.1])))] == NO_LABEL
