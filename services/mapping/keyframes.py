"""Keyframes as map updates: integrate a keyframe once, and replace its contribution when the SLAM
back end re-poses it or refines its pointmap (BundleFusion's de-integration, Dai et al. 2017).

A ``PerceptionFrame`` with ``kind`` set follows the map-update protocol (see the perception README):

* ``keyframe_new``    — integrate the keyframe and remember its contribution;
* ``keyframe_update`` — subtract the contribution it made last time, integrate the new one;
* ``tracking``        — the current frame: into the mapper's present layer (``mapper.py``), not
                        attributed to a keyframe.

``keyframe_new`` is a current frame too and also reaches the present layer. A ``keyframe_update``
whose pose moved (over ``repose_tolerance``) clears the present layer: it was built in the old
frame of reference. Only current frames advance the map's stamp (a ``keyframe_update`` re-sends
refined, not new, data).

The TSDF update of the integrator is a weighted running mean, so one frame's effect on a voxel is
a pair (d_k, w_k): the weighted mean of the truncated distances its rays wrote there and their
summed confidence. ``Contribution`` keeps exactly that, computed by integrating the frame alone into
a scratch layer (same integrator, same rays, no weight cap). Merging and removing it,

    integrate:      D ← (W·D + w_k·d_k) / (W + w_k),     W ← min(W + w_k, W_max)
    de-integrate:   D ← (W·D − w_k·d_k) / (W − w_k),     W ← W − w_k      (W − w_k ≤ ε → unknown)

are exact inverses. ``W`` here is the *uncapped* sum of the keyframes' weights, kept beside the
layer (one float per voxel, shifted with the volume); the layer's own weight is ``min(W, W_max)``
as the integrator's cap wants, but the cap would make subtraction remove evidence that was never
counted, so the mean is kept against the true sum. Contributions are
stored sparsely in *global* voxel indices (the volume's ``origin_index`` + local index), so they
stay valid when the rolling volume recentres; voxels that left the volume are simply skipped.
The layer's viewing direction behind surfaces (``view``, which the solid occupancy fills along)
becomes, for keyframes, the weight-averaged direction of the keyframes that saw the voxel so,
kept as a sum beside the weights: order-independent and removable like the rest.

The semantic layer: a keyframe's votes, cast alone into a scratch layer with the vote rule
(eq. 7–8), leave a *net vote* (ℓ_k, v_k) per voxel. The vote rule's state (one label and a margin)
cannot be taken back — removing a vote that flipped a label would forget what the label was — so
for keyframes each voxel keeps the evidence of its ``LABEL_SLOTS`` strongest labels (label, summed
net votes) beside the layer; adding or removing a keyframe adds or subtracts v_k in ℓ_k's slot, and
the layer shows the label of the largest evidence with the margin over the runner-up as its vote
(what the vote rule's weight measures). Order-independent and exactly removable; a fifth label
replaces the weakest slot (its evidence is then lost).

Memory is bounded: at most ``max_keyframes`` contributions and ``max_bytes`` in total; beyond that
the least recently written keyframe is *frozen* (its contribution stays in the map, its record is
dropped) and later updates of a frozen keyframe are ignored and counted, since they could no
longer be subtracted.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .config import MapperConfig, TsdfParams
from .layers import NO_LABEL, SemanticLayer, TsdfLayer
from .semantic_integrator import SemanticIntegrator
from .tsdf_integrator import TsdfIntegrator
from .volume import Volume, shift_array

NEW, UPDATE, TRACKING = "keyframe_new", "keyframe_update", "tracking"


class KeyframeData(NamedTuple):
    """A keyframe's content as ``KeyframeMap.integrate`` fuses it: the camera-frame pointmap, its
    confidence and labels, and the pose."""

    points: np.ndarray
    confidence: np.ndarray
    labels: np.ndarray
    T_WC: np.ndarray
LABEL_SLOTS = 4
_EPS = 1e-6


@dataclass(frozen=True)
class Contribution:
    """One keyframe's TSDF contribution: voxels (global index), mean truncated distance, weight."""

    index: np.ndarray  # (n, 3) int32, global voxel index
    d: np.ndarray  # (n,) float32
    w: np.ndarray  # (n,) float32
    label_index: np.ndarray  # (m, 3) int32, global voxel index of the net votes
    label: np.ndarray  # (m,) uint16
    vote: np.ndarray  # (m,) float32
    view: np.ndarray | None = None  # (n, 3) int8: the layer's per-voxel viewing direction, if it keeps one

    @property
    def nbytes(self) -> int:
        arrays = (self.index, self.d, self.w, self.label_index, self.label, self.vote, self.view)
        return sum(a.nbytes for a in arrays if a is not None)


class ContributionIntegrator:
    """Computes a frame's contribution, and adds it to or subtracts it from a ``TsdfLayer``."""

    def __init__(self, params: TsdfParams, surface_band: float):
        self.config = params
        # Same rays and weights as the mapper's integrator, but uncapped: w_k must be the whole sum.
        self.integrator = TsdfIntegrator(params.model_copy(update={"max_weight": 1e30}))
        self.semantic = SemanticIntegrator(params, surface_band)
        self.scratch: TsdfLayer | None = None
        self.scratch_sem = SemanticLayer((1, 1, 1))
        self.wsum: np.ndarray | None = None
        self.vsum: np.ndarray | None = None
        self.wsum_origin = np.zeros(3, np.int64)
        self.slot_label: np.ndarray | None = None
        self.slot_vote: np.ndarray | None = None
        self.slot_origin = np.zeros(3, np.int64)

    def contribution(self, volume: Volume, points: np.ndarray, confidence: np.ndarray, labels: np.ndarray,
                     T_WC: np.ndarray) -> tuple[Contribution, int, int]:
        """The frame's (d_k, w_k) and net votes (ℓ_k, v_k); also its ray and vote counts."""
        if self.scratch is None or self.scratch.tsdf.shape != volume.shape:
            self.scratch = TsdfLayer(volume.shape, self.config.truncation)
            self.scratch_sem = SemanticLayer(volume.shape)
        s, sem = self.scratch, self.scratch_sem
        s.clear()
        sem.clear()
        rays = self.integrator.integrate(volume, s, points, confidence, T_WC)
        votes = self.semantic.integrate(volume, sem, points, confidence, labels, T_WC)
        flat = np.flatnonzero(s.weight.reshape(-1))
        lflat = np.flatnonzero(sem.vote.reshape(-1))
        # A layer that keeps a per-voxel viewing direction (``view``, written by the integrator's
        # rays behind surfaces) gets the keyframe's directions too.
        view = getattr(s, "view", None)
        c = Contribution(self._global(volume, flat), s.tsdf.reshape(-1)[flat].copy(), s.weight.reshape(-1)[flat].copy(),
                         self._global(volume, lflat), sem.label.reshape(-1)[lflat].copy(),
                         sem.vote.reshape(-1)[lflat].copy(),
                         view.reshape(-1, view.shape[-1])[flat].copy() if view is not None else None)
        return c, rays, votes

    @staticmethod
    def _global(volume: Volume, flat: np.ndarray) -> np.ndarray:
        return (np.stack(np.unravel_index(flat, volume.shape), axis=1) + volume.origin_index).astype(np.int32)

    @staticmethod
    def _local(volume: Volume, index: np.ndarray) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
        local = index.astype(np.int64) - volume.origin_index
        inside = np.all((local >= 0) & (local < np.asarray(volume.shape)), axis=1)
        return tuple(local[inside].T), inside

    def _sums(self, volume: Volume, layer: TsdfLayer) -> np.ndarray:
        """The uncapped weight sums (and viewing-direction sums), following the volume as it recentres."""
        view = getattr(layer, "view", None)
        if self.wsum is None or self.wsum.shape != volume.shape:
            self.wsum = layer.weight.astype(np.float64)
            self.vsum = view.astype(np.float32) / 127.0 * self.wsum[..., None] if view is not None else None
        elif (self.wsum_origin != volume.origin_index).any():
            shift_array(self.wsum, volume.origin_index - self.wsum_origin, 0.0)
            if self.vsum is not None:
                shift_array(self.vsum, volume.origin_index - self.wsum_origin, 0.0)
        self.wsum_origin = volume.origin_index.copy()
        return self.wsum

    def apply(self, volume: Volume, layer: TsdfLayer, c: Contribution, sign: float,
              semantic: SemanticLayer | None = None, hit_ms: int | None = None) -> int:
        """Add (``sign`` = +1) or subtract (−1) a contribution; returns the voxels inside the volume.
        Adding with ``hit_ms`` (when the keyframe's frame was seen) stamps its surface voxels'
        ``hit`` (the decay of people, ``mapper.py``) unless a later frame did."""
        wsum = self._sums(volume, layer)
        ijk, inside = self._local(volume, c.index)
        d, w = c.d[inside].astype(np.float64), c.w[inside].astype(np.float64)
        W = wsum[ijk]
        # Anything else that wrote these voxels (frames without ``kind``, a reset) counts with the
        # layer's own, capped weight.
        Wl = layer.weight[ijk].astype(np.float64)
        W = np.where((Wl < self.config.max_weight) & (np.abs(W - Wl) > 1e-3 * np.maximum(Wl, 1.0)), Wl, W)
        D = layer.tsdf[ijk].astype(np.float64)
        tau = layer.truncation
        if sign > 0:
            W1 = W + w
            layer.tsdf[ijk] = (W * D + w * d) / W1
        else:
            W1 = W - w
            gone = W1 <= _EPS * np.maximum(w, 1.0)
            with np.errstate(divide="ignore", invalid="ignore"):
                D1 = np.clip((W * D - w * d) / np.where(gone, 1.0, W1), -tau, tau)
            W1 = np.where(gone, 0.0, W1)
            layer.tsdf[ijk] = np.where(gone, tau, D1)
        wsum[ijk] = W1
        layer.weight[ijk] = np.minimum(W1, self.config.max_weight)
        if sign > 0 and hit_ms is not None:
            surface = d < tau * (1.0 - 1e-6)  # some ray of the keyframe ended near this voxel
            sel = tuple(a[surface] for a in ijk)
            layer.hit[sel] = np.maximum(layer.hit[sel], np.int32(hit_ms))
        view = getattr(layer, "view", None)
        if view is not None and c.view is not None and self.vsum is not None:
            # The direction behind a surface: the weight-averaged direction of the keyframes that
            # saw the voxel so (not the last ray's, which would depend on the order keyframes
            # arrive and could not be taken back); it vanishes with the last of them.
            seen = c.view[inside].any(axis=1)
            sel = tuple(a[seen] for a in ijk)
            v = self.vsum[sel] + np.float32(sign) * w[seen, None].astype(np.float32) * c.view[inside][seen] / 127.0
            keep = np.linalg.norm(v, axis=1) > 1e-3 * np.maximum(W1[seen], 1.0)
            v = np.where(keep[:, None], v, 0.0).astype(np.float32)
            self.vsum[sel] = v
            unit = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-30)
            view[sel] = np.where(keep[:, None], np.rint(127.0 * unit), 0).astype(np.int8)
        if semantic is not None:
            self._vote(volume, semantic, c, sign)
        return int(inside.sum())

    def _slots(self, volume: Volume, layer: SemanticLayer) -> tuple[np.ndarray, np.ndarray]:
        """Per-voxel label evidence (labels, sums), following the volume; seeded from the layer."""
        if self.slot_label is None or self.slot_label.shape[:3] != volume.shape:
            self.slot_label = np.full((*volume.shape, LABEL_SLOTS), NO_LABEL, np.uint16)
            self.slot_vote = np.zeros((*volume.shape, LABEL_SLOTS), np.float32)
            self.slot_label[..., 0] = layer.label
            self.slot_vote[..., 0] = np.where(layer.label != NO_LABEL, layer.vote, 0.0)
        elif (self.slot_origin != volume.origin_index).any():
            shift_array(self.slot_label, volume.origin_index - self.slot_origin, NO_LABEL)
            shift_array(self.slot_vote, volume.origin_index - self.slot_origin, 0.0)
        self.slot_origin = volume.origin_index.copy()
        assert self.slot_vote is not None
        return self.slot_label, self.slot_vote

    def _vote(self, volume: Volume, layer: SemanticLayer, c: Contribution, sign: float) -> None:
        slot_label, slot_vote = self._slots(volume, layer)
        ijk, inside = self._local(volume, c.label_index)
        lk, vk = c.label[inside], c.vote[inside]
        L, E = slot_label[ijk], slot_vote[ijk]  # (m, K)
        rows = np.arange(lk.size)
        match = (L == lk[:, None]) & (E > 0)
        has = match.any(axis=1)
        if sign > 0:
            slot = np.where(has, match.argmax(axis=1), E.argmin(axis=1))  # else the empty / weakest slot
            E[rows, slot] = np.where(has, E[rows, slot] + vk, vk)
            L[rows, slot] = lk
        else:
            slot = match.argmax(axis=1)
            e = np.where(has, E[rows, slot] - vk, E[rows, slot])
            E[rows, slot] = np.where(e <= _EPS * np.maximum(vk, 1.0), 0.0, e)
        slot_label[ijk], slot_vote[ijk] = L, E
        top = E.argmax(axis=1)
        best = E[rows, top]
        runner_up = np.partition(E, -2, axis=1)[:, -2] if E.shape[1] > 1 else np.zeros_like(best)
        layer.label[ijk] = np.where(best > 0, L[rows, top], NO_LABEL)
        layer.vote[ijk] = np.where(best > 0, best - runner_up, 0.0)


class KeyframeMap:
    """Per-keyframe contributions of the mapper's TSDF, and the protocol's three message kinds.

    The bookkeeping only: the ``Mapper`` owns one, hands it the layers to change and applies what it
    returns (a re-pose clears its present layer), so this module knows no mapper."""

    def __init__(self, params: TsdfParams, surface_band: float, repose_tolerance: float, max_keyframes: int = 512,
                 max_bytes: int = 512 * 2**20):
        """``params``, ``surface_band``: the integration's, as the mapper's own integrators';
        ``repose_tolerance``: ``DynamicParams``'."""
        if max_keyframes < 1 or max_bytes < 1:
            raise ValueError("max_keyframes and max_bytes must be positive")
        self.config, self.repose_tolerance = params, repose_tolerance
        self.max_keyframes, self.max_bytes = max_keyframes, max_bytes
        self.integrator = ContributionIntegrator(params, surface_band)
        self.records: OrderedDict[int, Contribution] = OrderedDict()
        self.poses: dict[int, np.ndarray] = {}  # the pose each record was integrated at
        self.seen_ms: dict[int, int] = {}  # when each keyframe's own frame was seen (mapper clock)
        self.frozen: set[int] = set()
        self.nbytes = 0
        self.counts = {NEW: 0, UPDATE: 0, TRACKING: 0, "frozen_updates": 0, "evicted": 0}

    def __len__(self) -> int:
        return len(self.records)

    def admit(self, kind: str | None, kid: int) -> bool:
        """Does a frame of ``kind`` for keyframe ``kid`` change the keyframes' contributions? An
        update of a frozen keyframe does not (it could no longer be subtracted): counted, ignored."""
        if kind == UPDATE and kid in self.frozen:
            self.counts["frozen_updates"] += 1
            return False
        return kind in (NEW, UPDATE)

    def integrate(self, volume: Volume, tsdf: TsdfLayer, semantic: SemanticLayer, kind: str, kid: int,
                  frame: KeyframeData, now_ms: int) -> tuple[int, int, bool]:
        """A ``keyframe_new`` or ``keyframe_update`` (one ``admit`` let through) into the mapper's
        ``tsdf``/``semantic``: the keyframe's last contribution out, the new one in. Returns the
        new contribution's rays and votes, and whether the keyframe was re-posed (its pose moved
        over ``repose_tolerance``: the caller's present layer is then in an old frame of reference)."""
        pose = np.asarray(frame.T_WC, dtype=np.float64)
        reposed = False
        old = self.records.pop(kid, None) if kind == UPDATE else None
        if old is not None:
            self.nbytes -= old.nbytes
            self.integrator.apply(volume, tsdf, old, -1.0, semantic)
            reposed = self._reposed(self.poses[kid], pose, volume.voxel_size)
        elif kind == NEW and kid in self.records:  # an id reused (a restarted sender): keep both
            self.nbytes -= self.records.pop(kid).nbytes
        if kind == NEW or kid not in self.seen_ms:
            self.seen_ms[kid] = now_ms
        contrib, rays, votes = self.integrator.contribution(volume, *frame)
        self.integrator.apply(volume, tsdf, contrib, +1.0, semantic, self.seen_ms[kid])
        self.records[kid] = contrib
        self.poses[kid] = pose.copy()
        self.frozen.discard(kid)
        self.nbytes += contrib.nbytes
        self._bound()
        return rays, votes, reposed

    @classmethod
    def of(cls, config: MapperConfig, max_keyframes: int = 512, max_bytes: int = 512 * 2**20) -> KeyframeMap:
        """Wired from a whole mapper configuration: its ``TsdfParams``, surface band and
        ``repose_tolerance``."""
        return cls(config.tsdf, config.surface_band, config.repose_tolerance, max_keyframes, max_bytes)

    def count(self, kind: str | None) -> None:
        """One more frame of ``kind`` seen (anything that is no keyframe counts as tracking)."""
        self.counts[kind if kind in self.counts else TRACKING] += 1

    def _reposed(self, before: np.ndarray, after: np.ndarray, voxel_size: float) -> bool:
        """Did a keyframe's pose move enough to re-pose the world (``repose_tolerance``)?"""
        rel = np.linalg.inv(before) @ after
        angle = float(np.arccos(np.clip((np.trace(rel[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
        moved = max(float(np.linalg.norm(rel[:3, 3])), angle * self.config.max_depth)
        return moved > self.repose_tolerance

    def _bound(self) -> None:
        while len(self.records) > 1 and (len(self.records) > self.max_keyframes or self.nbytes > self.max_bytes):
            kid, c = self.records.popitem(last=False)
            self.poses.pop(kid, None)
            self.seen_ms.pop(kid, None)
            self.nbytes -= c.nbytes
            self.frozen.add(kid)
            self.counts["evicted"] += 1
