"""The paper's keyframe fusion rules over flattened keyframe pixels, and the fused state of a keyframe.

Layout follows MASt3R-SLAM: a keyframe's pointmap is ``X (H·W, 3)`` in its own camera frame with
confidence ``C (H·W,)``; matches are given per **keyframe** pixel ξ: ``idx_f2k[ξ]`` is the linear
index ``v·W + u`` of the matching pixel in the current frame, ``valid_match_k[ξ]`` whether the
match exists, and ``Qk[ξ]`` its quality.

Geometry, eq. (2) — confidence-weighted running mean (MASt3R-SLAM's ``weighted_pointmap``)::

    X̃ ← (C̃·X̃ + C·X) / (C̃ + C),      C̃ ← C̃ + C

Semantics, eq. (7)–(8) — a vote weight per keyframe pixel, with q the match confidence::

    w ← w + q   if the matched frame label agrees with the keyframe label ℓ
    w ← w − q   otherwise;   when w < 0:  ℓ ← the observed label,  w ← −w

The ``mast3r`` backend votes with the numpy functions here (its geometry is MASt3R-SLAM's own);
the ``sim`` backend fuses both in one compiled pass (``kernels.fuse_kernel``) into a
:class:`KeyframeFusion`.

The paper only says the label is replaced "when the weight becomes negative"; we then keep the
surplus −w as the new label's weight (so one confident contradicting observation replaces a
weakly held label, but a label held by many votes needs as many contrary votes to flip).
"""

from __future__ import annotations

import numpy as np

#: MASt3R-SLAM's default threshold on the match quality for trusted matches (``tracking.Q_conf``).
Q_CONF = 1.5


def vote_fuse(labels_k: np.ndarray, weights_k: np.ndarray, observed: np.ndarray, q: np.ndarray,
              mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (7)–(8) for every pixel where ``mask`` holds; returns new ``(labels, weights)``."""
    q = np.asarray(q, np.float64).reshape(-1)
    if mask is None:
        mask = np.ones(q.shape, bool)
    agree = observed == labels_k
    w = weights_k + np.where(mask, np.where(agree, q, -q), 0.0)
    flip = mask & (w < 0)
    labels = np.where(flip, observed, labels_k).astype(labels_k.dtype, copy=False)
    return labels, np.where(flip, -w, w).astype(weights_k.dtype, copy=False)


def match_confidence(Qff: np.ndarray, Qkf: np.ndarray, idx_f2k: np.ndarray) -> np.ndarray:
    """MASt3R-SLAM's match quality per keyframe pixel: ``Qk = sqrt(Qff[idx_f2k] · Qkf)``, where
    ``Qff`` is the frame's own descriptor confidence (per frame pixel) and ``Qkf`` the
    keyframe's confidence in the cross prediction (per keyframe pixel)."""
    return np.sqrt(Qff.reshape(-1)[idx_f2k.reshape(-1)] * Qkf.reshape(-1))


def transfer_labels(labels_frame: np.ndarray, idx_f2k: np.ndarray, valid_match_k: np.ndarray, Qk: np.ndarray,
                    Q_conf: float = Q_CONF) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame labels carried onto keyframe pixels through the tracker's matches.

    Returns ``(observed, trusted, q)`` per keyframe pixel: ``observed = labels_frame.flatten()
    [idx_f2k]``, ``trusted = valid_match_k & (Qk > Q_conf)``, ``q = Qk`` (zero where untrusted)."""
    idx = idx_f2k.reshape(-1).astype(np.int64)
    flat = labels_frame.reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= flat.size):
        raise ValueError("idx_f2k points outside the frame")
    q = Qk.reshape(-1).astype(np.float64)
    trusted = valid_match_k.reshape(-1).astype(bool) & (q > Q_conf)
    return flat[idx], trusted, np.where(trusted, q, 0.0)


class KeyframeFusion:
    """Fused state of one keyframe: pointmap, confidence, labels and vote weights (flattened)."""

    def __init__(self, keyframe_id: int, height: int, width: int, X: np.ndarray, C: np.ndarray, labels: np.ndarray,
                 label_weight: np.ndarray | float = 1.0):
        self.id = keyframe_id
        self.height, self.width = height, width
        self.X = np.array(X, np.float32).reshape(-1, 3)
        self.C = np.array(C, np.float32).reshape(-1)
        self.labels = np.array(labels, np.uint16).reshape(-1)
        self.weights = np.broadcast_to(np.asarray(label_weight, np.float32), self.C.shape).copy()
        self.updates = 0
