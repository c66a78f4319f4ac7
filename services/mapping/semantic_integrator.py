"""Per-pixel labels → per-voxel semantic labels with the paper's vote rule (eq. 7–8).

Each voxel keeps a label ℓ and a vote weight w. An observation of label y with
confidence q updates them as

    w ← w + q   if y = ℓ,
    w ← w − q   otherwise, and if then w < 0:  ℓ ← y,  w ← −w.

The label is replaced only when the weight goes negative, exactly as the paper states;
after a replacement the weight keeps the surplus of evidence for the new label (−w ≥ 0),
so one disagreeing observation never outweighs a long history. A voxel without votes holds
``NO_LABEL`` with w = 0, so its first observation replaces it (w = −q < 0 → ℓ = y, w = q).

The voxels voted for are those along each pixel's ray whose centre lies within the surface
band |r − t_c| ≤ ``surface_band`` — the same band the occupancy extracts, so every voxel
that supports the surface has been labelled by the pixels that observed it.
"""

from __future__ import annotations

import numpy as np

from riskfield.protocol.kernels import Layout, view1, view2

from ..runtime.jit import jit
from .config import TsdfParams
from .layers import SemanticLayer
from .raycast import pixel_ray, ray_voxels
from .volume import Volume

#: One frame's numbers as ``_integrate`` reads them: the camera (rotation, centre), the volume
#: (origin, voxel size), the surface band and ``TsdfParams``' thresholds, in a float64 buffer, and
#: the pixel stride in an int64 one.
FLOATS = Layout("SemanticFloats", [("R", (3, 3)), ("camera", (3,)), ("origin", (3,)), ("voxel", (1,)),
                                   ("band", (1,)), ("q_min", (1,)), ("r_min", (1,)), ("r_max", (1,))])
INTS = Layout("SemanticInts", [("stride", (1,))])
_SF, _SI = FLOATS.table(), INTS.table()
_F, _I = FLOATS.slot, INTS.slot


@jit(error_model="numpy")
def vote(label: int, weight: float, observed: int, q: float) -> tuple[int, float]:
    """One application of the vote rule; returns the new (label, weight)."""
    if observed == label:
        return label, weight + q
    weight -= q
    if weight < 0.0:
        return observed, -weight
    return label, weight


@jit(error_model="numpy")
def _integrate(frame: tuple, layer: tuple, fl: np.ndarray, it: np.ndarray) -> int:
    """Vote ``frame`` = (points, confidence, labels) into ``layer`` = the ``SemanticLayer``'s (label,
    vote), with the frame's numbers ``fl``, ``it`` (``FLOATS``, ``INTS``); the vote count."""
    points, conf, labels = frame
    lab, votes = layer
    R, vs, band = view2(fl, _SF, _F.R), view1(fl, _SF, _F.voxel)[0], view1(fl, _SF, _F.band)[0]
    q_min, r_min, r_max = view1(fl, _SF, _F.q_min)[0], view1(fl, _SF, _F.r_min)[0], view1(fl, _SF, _F.r_max)[0]
    stride = view1(it, _SI, _I.stride)[0]
    h, w = conf.shape
    shape = np.array(lab.shape, dtype=np.int64)
    buf = np.empty((shape.sum() + 4, 3), dtype=np.int64)
    o = (view1(fl, _SF, _F.camera) - view1(fl, _SF, _F.origin)) / vs
    dw = np.empty(3)
    di = np.empty(3)
    n_votes = 0
    for v in range(0, h, stride):
        for u in range(0, w, stride):
            q, r = pixel_ray(points, conf, R, v, u, q_min, r_min, dw)
            if r < 0.0 or r > r_max:
                continue
            for a in range(3):
                di[a] = dw[a] / vs
            y = labels[v, u]
            n = ray_voxels(o, di, r - band - 0.87 * vs, r + band + 0.87 * vs, shape, buf)
            for m in range(n):
                i, j, k = buf[m, 0], buf[m, 1], buf[m, 2]
                tc = (i - o[0]) * vs * dw[0] + (j - o[1]) * vs * dw[1] + (k - o[2]) * vs * dw[2]
                if abs(r - tc) > band:
                    continue
                nl, nw = vote(lab[i, j, k], votes[i, j, k], y, q)
                lab[i, j, k] = nl
                votes[i, j, k] = nw
                n_votes += 1
    return n_votes


class SemanticIntegrator:
    """Fuses per-pixel ADE20K labels into a ``SemanticLayer`` (see the module docstring)."""

    def __init__(self, params: TsdfParams, surface_band: float):
        # the frame's sampling is the TSDF's (TsdfParams); labels are voted in the occupancy's
        # surface band (OccupancyParams.surface_band_vox × the voxel size), as in the paper
        self.config, self.surface_band = params, surface_band
        self._floats = np.zeros(Layout.size(_SF))
        self._ints = np.zeros(Layout.size(_SI), np.int64)

    def integrate(self, volume: Volume, layer: SemanticLayer, points: np.ndarray, confidence: np.ndarray,
                  labels: np.ndarray, T_WC: np.ndarray) -> int:
        """Vote one frame's labels into the voxels near each observed surface point; the vote count."""
        c, fl, it = self.config, self._floats, self._ints
        T = np.asarray(T_WC, dtype=np.float64)
        FLOATS.view(fl, _SF, "R")[:] = T[:3, :3]
        FLOATS.view(fl, _SF, "camera")[:] = T[:3, 3]
        FLOATS.view(fl, _SF, "origin")[:] = volume.origin
        for name, value in (("voxel", volume.voxel_size), ("band", self.surface_band), ("q_min", c.min_confidence),
                            ("r_min", c.min_depth), ("r_max", c.max_depth)):
            FLOATS.view(fl, _SF, name)[0] = value
        INTS.view(it, _SI, "stride")[0] = c.pixel_stride
        frame = (np.asarray(points, dtype=np.float32), np.asarray(confidence, dtype=np.float32),
                 np.asarray(labels, dtype=np.uint16))
        return int(_integrate(frame, (layer.label, layer.vote), fl, it))
