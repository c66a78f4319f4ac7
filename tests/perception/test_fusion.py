"""The paper's fusion rules: eq. (2) pointmap fusion, eq. (7)-(8) vote fusion, label transfer
through idx_f2k exactly as MASt3R-SLAM defines it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from riskfield.services.perception.fusion import (
    KeyframeFusion,
    fuse_pointmap,
    match_confidence,
    scatter_to_frame,
    transfer_labels,
    vote_fuse,
)

finite = st.floats(-100, 100, allow_nan=False, width=32)
conf = st.floats(0, 50, allow_nan=False, width=32)


@settings(max_examples=60, deadline=None)
@given(arrays(np.float32, (20, 3), elements=finite), arrays(np.float32, 20, elements=conf),
       arrays(np.float32, (20, 3), elements=finite), arrays(np.float32, 20, elements=conf),
       arrays(bool, 20))
def test_fuse_pointmap_is_the_confidence_weighted_mean(Xk, Ck, X, C, mask):
    Xn, Cn = fuse_pointmap(Xk, Ck, X, C, mask)
    c = np.where(mask, C, 0).astype(np.float64)
    total = Ck.astype(np.float64) + c
    expect = np.where((total > 0)[:, None], (Ck[:, None] * Xk.astype(np.float64) + c[:, None] * X)
                      / np.where(total > 0, total, 1)[:, None], Xk)
    np.testing.assert_allclose(Xn, expect, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(Cn, total, rtol=1e-6)
    # The fused point lies between the two (a convex combination), coordinate-wise.
    lo, hi = np.minimum(Xk, X), np.maximum(Xk, X)
    sel = mask & (C > 0)
    assert np.all(Xn[sel] >= lo[sel] - 1e-3) and np.all(Xn[sel] <= hi[sel] + 1e-3)
    np.testing.assert_array_equal(Xn[~mask], Xk[~mask])


def test_fusing_many_noisy_observations_converges_to_the_truth():
    rng = np.random.default_rng(0)
    truth = rng.uniform(-2, 2, (1000, 3)).astype(np.float32)
    X, C = truth + rng.normal(0, 0.1, truth.shape).astype(np.float32), np.ones(1000, np.float32)
    for _ in range(99):
        X, C = fuse_pointmap(X, C, truth + rng.normal(0, 0.1, truth.shape).astype(np.float32), np.ones(1000))
    err = (X - truth).std()
    assert err == pytest.approx(0.1 / np.sqrt(100), rel=0.15)  # the mean of 100 samples
    assert np.all(C == 100)


def test_vote_rule_cases():
    labels = np.array([1, 1, 1, 1], np.uint16)
    w = np.array([1.0, 1.0, 0.2, 1.0], np.float32)
    obs = np.array([1, 2, 2, 2], np.uint16)
    q = np.array([0.5, 0.5, 0.5, 3.0])
    mask = np.array([True, True, True, False])
    L, W = vote_fuse(labels, w, obs, q, mask)
    assert L.tolist() == [1, 1, 2, 1]  # agree; weakened; flipped (w < 0); untrusted: untouched
    np.testing.assert_allclose(W, [1.5, 0.5, 0.3, 1.0], atol=1e-6)


def test_a_label_held_by_many_votes_needs_as_many_to_flip():
    L, W = np.array([5], np.uint16), np.array([0.0], np.float32)
    for _ in range(4):
        L, W = vote_fuse(L, W, np.array([5], np.uint16), np.array([1.0]))
    flips = 0
    while L[0] == 5:
        L, W = vote_fuse(L, W, np.array([9], np.uint16), np.array([1.0]))
        flips += 1
    assert flips == 5 and L[0] == 9  # 4 votes for 5 (w = 4) plus the one that makes it negative


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 6), st.data())
def test_transfer_labels_is_flat_index_through_idx_f2k(h, w, data):
    labels = data.draw(arrays(np.uint16, (h, w), elements=st.integers(0, 149)))
    n = h * w
    idx = data.draw(arrays(np.int64, n, elements=st.integers(0, n - 1)))
    valid = data.draw(arrays(bool, n))
    Qk = data.draw(arrays(np.float64, n, elements=st.floats(0, 5)))
    obs, trusted, q = transfer_labels(labels, idx, valid, Qk, 1.5)
    for k in range(n):
        v, u = divmod(int(idx[k]), w)
        assert obs[k] == labels[v, u]  # idx is v·W + u in the frame
        assert trusted[k] == (valid[k] and Qk[k] > 1.5)
        assert q[k] == (Qk[k] if trusted[k] else 0.0)


def test_transfer_rejects_out_of_range_indices():
    with pytest.raises(ValueError):
        transfer_labels(np.zeros((2, 2), np.uint16), np.array([0, 4]), np.ones(2, bool), np.full(2, 3.0))


def test_match_confidence_is_mast3r_qk():
    Qff = np.array([[[1.0], [4.0], [9.0]]])  # (1, HW, 1) like the tracker's tensors
    Qkf = np.array([[[4.0], [1.0], [1.0]]])
    idx = np.array([[2, 0, 1]])
    np.testing.assert_allclose(match_confidence(Qff, Qkf, idx), [6.0, 1.0, 2.0])


def test_scatter_back_to_frame():
    frame = np.zeros((2, 3), np.uint16)
    out = scatter_to_frame(np.array([7, 8, 9], np.uint16), np.array([5, 0, 2]), np.array([True, False, True]), frame)
    assert out.tolist() == [[0, 0, 9], [0, 0, 7]] and frame.sum() == 0


def test_keyframe_fusion_object():
    kf = KeyframeFusion(3, 1, 3, np.zeros((3, 3)), np.ones(3), np.array([1, 1, 1]), label_weight=0.5)
    trusted = kf.fuse(np.ones((3, 3)), np.array([1.0, 1.0, 1.0]), np.array([[2, 1, 2]], np.uint16),
                      np.array([0, 1, 2]), np.array([True, True, False]), np.array([2.0, 2.0, 2.0]))
    assert trusted.tolist() == [True, True, False]
    np.testing.assert_allclose(kf.X[:, 0], [0.5, 0.5, 0.0])
    assert kf.labels.tolist() == [2, 1, 1] and kf.updates == 1
