"""The paper's fusion rules: eq. (2) pointmap fusion, eq. (7)-(8) vote fusion, label transfer
through idx_f2k exactly as MASt3R-SLAM defines it; the numpy renderings of eq. (2) and of the
keyframe fusion (``oracles.sim_perception``) and the sim backend's kernels that run them."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from oracles.sim_perception import fuse, fuse_pointmap, scatter_to_frame
from riskfield.services.perception import kernels
from riskfield.services.perception.fusion import KeyframeFusion, match_confidence, transfer_labels, vote_fuse

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
    values, idx, trusted = np.array([7, 8, 9], np.uint16), np.array([5, 0, 2]), np.array([True, False, True])
    out = scatter_to_frame(values, idx, trusted, frame)
    assert out.tolist() == [[0, 0, 9], [0, 0, 7]] and frame.sum() == 0
    labels = frame.copy().reshape(-1)  # the sim backend's kernel, labels only (no points)
    kernels.current_frame_kernel(np.eye(4), (np.zeros((3, 3), np.float32), values), (idx, trusted, np.full(3, 2.0)),
                                 1.5, False, (np.zeros((6, 3), np.float32), labels))
    np.testing.assert_array_equal(labels.reshape(2, 3), out)


def test_keyframe_fusion_object():
    def keyframe() -> KeyframeFusion:
        return KeyframeFusion(3, 1, 3, np.zeros((3, 3)), np.ones(3), np.array([1, 1, 1]), label_weight=0.5)

    kf = keyframe()
    points, conf, labels = np.ones((3, 3), np.float32), np.ones(3, np.float32), np.array([[2, 1, 2]], np.uint16)
    idx, valid, Qk = np.array([0, 1, 2]), np.array([True, True, False]), np.array([2.0, 2.0, 2.0])
    trusted = fuse(kf, points, conf, labels, idx, valid, Qk)
    assert trusted.tolist() == [True, True, False]
    np.testing.assert_allclose(kf.X[:, 0], [0.5, 0.5, 0.0])
    assert kf.labels.tolist() == [2, 1, 1] and kf.updates == 1
    # the sim backend's kernel (T_KC the identity: the frame's points are the keyframe's)
    k = keyframe()
    out = (*(np.empty_like(a) for a in (k.X, k.C, k.labels, k.weights)), np.empty(3, bool))
    kernels.fuse_kernel(np.eye(4), (points, conf, labels.reshape(-1)), (idx, valid, Qk), 1.5,
                        (k.X, k.C, k.labels, k.weights), out)
    for name, x, y in zip(("X", "C", "labels", "weights", "trusted"), (kf.X, kf.C, kf.labels, kf.weights, trusted),
                          out, strict=True):
        np.testing.assert_array_equal(x, y, err_msg=name)
