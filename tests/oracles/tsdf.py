"""The TSDF of a frame by one ray per pixel, as a test oracle of the mapper's integrators: the
merged rays (``services/mapping/tsdf_integrator.py``, one ray per voxel the points fall in) and the
projective pass (``projective_integrator.py``) are checked against it (tests/mapping/test_tsdf.py,
test_projective.py).

``RayTsdf`` casts every ``pixel_stride``-th pixel's own ray through the surface band, and carves
free space along every ``carve_stride``-th pixel's ray, with the same per-voxel update and the same
numbers (``TsdfParams``) as the merged rays: the simplest reading of the update the module docstring
of ``tsdf_integrator.py`` states. Compiled with numba (without its on-disk cache, so the tests
leave no cache files behind): a frame is tens of thousands of rays.
"""

from __future__ import annotations

import numba
import numpy as np

from riskfield.protocol.kernels import view1, view2
from riskfield.services.mapping.config import TsdfParams
from riskfield.services.mapping.layers import TsdfLayer
from riskfield.services.mapping.raycast import pixel_ray
from riskfield.services.mapping.tsdf_integrator import _F, _I, _TF, _TI, TsdfIntegrator, _ray
from riskfield.services.mapping.volume import Volume


@numba.njit(error_model="numpy")
def _integrate(frame: tuple, layer: tuple, fl: np.ndarray, it: np.ndarray, carve_stride: int) -> int:
    """Per-pixel rays of ``frame`` = (points, confidence): every ``stride``-th pixel updates its
    band, every ``carve_stride``-th carves."""
    points, conf = frame
    R = view2(fl, _TF, _F.R)
    vs, trunc = view1(fl, _TF, _F.voxel)[0], view1(fl, _TF, _F.trunc)[0]
    q_min, r_min, r_max = view1(fl, _TF, _F.q_min)[0], view1(fl, _TF, _F.r_min)[0], view1(fl, _TF, _F.r_max)[0]
    carve_scale = view1(fl, _TF, _F.carve_scale)[0]
    stride, carve = view1(it, _TI, _I.stride)[0], view1(it, _TI, _I.carve)[0] != 0
    h, w = conf.shape
    buf = np.empty((view1(it, _TI, _I.shape).sum() + 4, 3), dtype=np.int64)
    geo = np.empty((3, 3))
    o, dw, di = geo[0], geo[1], geo[2]
    o[:] = (view1(fl, _TF, _F.camera) - view1(fl, _TF, _F.origin)) / vs  # camera centre in index units
    used = 0
    for pass_ in range(2):
        if pass_ == 1 and not carve:
            break
        s = stride if pass_ == 0 else carve_stride
        for v in range(0, h, s):
            for u in range(0, w, s):
                q, r = pixel_ray(points, conf, R, v, u, q_min, r_min, dw)
                if r < 0.0:
                    continue
                for a in range(3):
                    di[a] = dw[a] / vs
                if pass_ == 0:
                    if r > r_max:
                        continue
                    n = _ray(layer, fl, it, geo, r, r - trunc, r + trunc, q, buf)
                else:
                    t1 = min(r, r_max) - trunc
                    if t1 <= r_min:
                        continue
                    n = _ray(layer, fl, it, geo, r, r_min, t1, q * carve_scale, buf)
                if n > 0:
                    used += 1
    return used


class RayTsdf(TsdfIntegrator):
    """``TsdfIntegrator`` with one ray per pixel instead of per voxel: every ``pixel_stride``-th
    pixel updates its surface band, every ``carve_stride``-th pixel also carves free space."""

    def __init__(self, params: TsdfParams, carve_stride: int = 4):
        super().__init__(params)
        self.carve_stride = int(carve_stride)

    def integrate(self, volume: Volume, layer: TsdfLayer, points: np.ndarray, confidence: np.ndarray,
                  T_WC: np.ndarray, now_ms: int = 0) -> int:
        fl, it = self._numbers(volume, layer, np.asarray(T_WC, dtype=np.float64), now_ms)
        frame = (np.asarray(points, dtype=np.float32), np.asarray(confidence, dtype=np.float32))
        arrays = (layer.tsdf, layer.weight, layer.view, layer.hit)
        return int(_integrate(frame, arrays, fl, it, self.carve_stride))
