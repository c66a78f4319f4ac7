"""Compiled per-pixel kernels of the ``sim`` backend: keyframe matching, fusion and the current
frame's message in one pass each.

They compute exactly what the numpy reference does (``SimBackend.match`` with ``numpy=True``,
``transform_points`` + ``KeyframeFusion.fuse``, ``SimBackend._message``), in the same dtypes and
operation order, so their outputs are bit-identical (tests/perception/test_kernels.py checks this on
real frames). The numpy path allocates a dozen full-frame temporaries per step; on the two shared
cores that was 25 of the backend's ~37 ms per frame. Without numba (the ``perception`` extra alone) the numpy path runs.
"""

from __future__ import annotations

import numpy as np

from ..runtime.jit import HAVE_NUMBA, njit

if HAVE_NUMBA:

    @njit(cache=True, nogil=True)
    def match_kernel(T_CW: np.ndarray, world: np.ndarray, kf_valid: np.ndarray, C0: np.ndarray,
                     truth_points: np.ndarray, truth_valid: np.ndarray, C_t: np.ndarray, h: int, w: int,
                     fx: float, fy: float, cx: float, cy: float, tol_abs: float, tol_rel: float,
                     idx: np.ndarray, valid: np.ndarray, Qk: np.ndarray) -> int:
        """Per keyframe pixel: reproject its true world point into the current camera (``T_CW``),
        accept the pixel it lands on if the true depth there agrees; fills ``idx``, ``valid``,
        ``Qk``, returns the number of valid matches (``SimBackend.match``)."""
        n_valid = 0
        for k in range(world.shape[0]):
            x0, y0, z0 = world[k, 0], world[k, 1], world[k, 2]
            # transform_points: R[i,0]·x + R[i,1]·y + R[i,2]·z + t[i], left to right, float64
            x = T_CW[0, 0] * x0 + T_CW[0, 1] * y0 + T_CW[0, 2] * z0 + T_CW[0, 3]
            y = T_CW[1, 0] * x0 + T_CW[1, 1] * y0 + T_CW[1, 2] * z0 + T_CW[1, 3]
            z = T_CW[2, 0] * x0 + T_CW[2, 1] * y0 + T_CW[2, 2] * z0 + T_CW[2, 3]
            idx[k] = 0
            valid[k] = False
            Qk[k] = 0.0
            if not (kf_valid[k] and z > 1e-6):
                continue
            # PinholeCamera.project (z > 1e-6 > 1e-9, so zs = z)
            u = np.rint(fx * x / z + cx)
            v = np.rint(fy * y / z + cy)
            if not (u >= 0 and u < w and v >= 0 and v < h):
                continue
            i = np.int64(v) * w + np.int64(u)
            idx[k] = i
            if not truth_valid[i]:
                continue
            tol = tol_abs + tol_rel * z
            if abs(np.float64(truth_points[i, 2]) - z) < tol:
                valid[k] = True
                Qk[k] = np.sqrt(C0[k] * np.float64(C_t[i]))
                n_valid += 1
        return n_valid

    @njit(cache=True, nogil=True)
    def fuse_kernel(T_KC: np.ndarray, points: np.ndarray, conf: np.ndarray, labels_frame: np.ndarray,
                    idx: np.ndarray, valid_match: np.ndarray, Qk: np.ndarray, Q_conf: float, X: np.ndarray,
                    C: np.ndarray, labels: np.ndarray, weights: np.ndarray, X_out: np.ndarray, C_out: np.ndarray,
                    labels_out: np.ndarray, weights_out: np.ndarray, trusted: np.ndarray) -> None:
        """One tracked frame fused into a keyframe (eq. 2 and 7–8, ``KeyframeFusion.fuse``): the
        frame's point matched to keyframe pixel ξ, moved into the keyframe frame by ``T_KC``
        (float64, stored as float32 like ``transform_points(..., np.float32)``), averaged by
        confidence with ``X, C``; its label votes on ``labels, weights`` over trusted matches. The
        results go to the ``*_out`` arrays (new ones, as the numpy path makes: a message built
        from the previous state keeps it)."""
        for k in range(X.shape[0]):
            i = idx[k]
            x0, y0, z0 = points[i, 0], points[i, 1], points[i, 2]
            q = Qk[k]
            t = valid_match[k] and q > Q_conf
            trusted[k] = t
            ck = np.float64(C[k])
            c1 = np.float64(conf[i]) if t else 0.0
            total = ck + c1
            for j in range(3):
                if total > 0:
                    xj = np.float32(T_KC[j, 0] * x0 + T_KC[j, 1] * y0 + T_KC[j, 2] * z0 + T_KC[j, 3])
                    X_out[k, j] = np.float32((ck * np.float64(X[k, j]) + c1 * np.float64(xj)) / total)
                else:
                    X_out[k, j] = X[k, j]
            C_out[k] = np.float32(total)
            labels_out[k] = labels[k]
            weights_out[k] = weights[k]
            if t:
                wk = np.float64(weights[k]) + (q if labels_frame[i] == labels[k] else -q)
                if wk < 0:
                    labels_out[k] = labels_frame[i]
                    wk = -wk
                weights_out[k] = np.float32(wk)

    @njit(cache=True, nogil=True)
    def incidence_kernel(points: np.ndarray, valid: np.ndarray, cos: np.ndarray) -> None:
        """|cos| of the viewing ray to the surface normal per pixel, the normal from neighbouring
        points (``degrade.normals_from_pointmap`` then ``cos_incidence``, in float32 like them)."""
        h, w = valid.shape
        one, tiny = np.float32(1.0), np.float32(1e-12)
        for v in range(h):
            vm, vp = max(v - 1, 0), min(v + 1, h - 1)
            for u in range(w):
                um, up = max(u - 1, 0), min(u + 1, w - 1)
                p0, p1, p2 = points[v, u, 0], points[v, u, 1], points[v, u, 2]
                dx0 = points[v, up, 0] - points[v, um, 0]
                dx1 = points[v, up, 1] - points[v, um, 1]
                dx2 = points[v, up, 2] - points[v, um, 2]
                dy0 = points[vp, u, 0] - points[vm, u, 0]
                dy1 = points[vp, u, 1] - points[vm, u, 1]
                dy2 = points[vp, u, 2] - points[vm, u, 2]
                ok = valid[v, u] and valid[v, up] and valid[v, um] and valid[vp, u] and valid[vm, u]
                n0 = dx1 * dy2 - dx2 * dy1
                n1 = dx2 * dy0 - dx0 * dy2
                n2 = dx0 * dy1 - dx1 * dy0
                norm = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
                ok = ok and norm > tiny
                if not ok:
                    cos[v, u] = one
                    continue
                facing = n0 * p0 + n1 * p1 + n2 * p2
                d = -norm if facing > 0 else norm
                n0, n1, n2 = n0 / d, n1 / d, n2 / d
                r = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
                dot = n0 * p0 + n1 * p1 + n2 * p2
                c = abs(dot) / (r if r > 0 else one)
                cos[v, u] = min(max(c, np.float32(0.0)), one)

    @njit(cache=True, nogil=True)
    def depth_noise_kernel(points: np.ndarray, valid: np.ndarray, z: np.ndarray, cos: np.ndarray,
                           normal: np.ndarray, e: np.ndarray, a: float, b: float, c_gain: float,
                           noisy: np.ndarray, conf: np.ndarray) -> None:
        """Range noise along each pixel's ray and the confidence (``Degrader.observe``): ``normal``
        is the standard normal draw, ``e = exp(−z / z_scale)`` (numpy's exp, for identical bits)."""
        h, w = valid.shape
        cmin, g = np.float32(0.2), np.float32(c_gain)
        for v in range(h):
            for u in range(w):
                if not valid[v, u]:
                    noisy[v, u, 0] = 0.0
                    noisy[v, u, 1] = 0.0
                    noisy[v, u, 2] = 0.0
                    conf[v, u] = 0.0
                    continue
                zz = z[v, u]
                c = cos[v, u]
                sigma = (a + b * zz * zz) / np.float64(max(c, cmin))
                noise = normal[v, u] * sigma
                s = max((zz + noise) / (zz if zz > 0 else 1.0), 0.05)
                for j in range(3):
                    noisy[v, u, j] = np.float32(np.float64(points[v, u, j]) * s)
                conf[v, u] = np.float32(1.0 + np.float64(g * c) * e[v, u])

    @njit(cache=True, nogil=True)
    def current_frame_kernel(T_CK: np.ndarray, X: np.ndarray, labels_k: np.ndarray, idx: np.ndarray,
                             valid_match: np.ndarray, Qk: np.ndarray, Q_conf: float, with_points: bool,
                             points: np.ndarray, labels: np.ndarray) -> None:
        """The current frame's message (``SimBackend._message``): over trusted matches (valid and
        Qk > Q_conf), the keyframe's fused label ``labels_k[ξ]`` written at its frame pixel
        ``idx[ξ]`` (``fusion.scatter_to_frame``) and, ``with_points``, its fused point moved into the
        camera by ``T_CK`` (float64, stored as float32 like ``transform_points(..., np.float32)``).
        ``points`` and ``labels`` are the frame's own copies, written in place; a pixel two keyframe
        pixels land on keeps the later one, as numpy's fancy assignment does."""
        for k in range(X.shape[0]):
            if not (valid_match[k] and Qk[k] > Q_conf):
                continue
            i = idx[k]
            labels[i] = labels_k[k]
            if with_points:
                x0 = np.float64(X[k, 0])
                y0 = np.float64(X[k, 1])
                z0 = np.float64(X[k, 2])
                for j in range(3):
                    points[i, j] = np.float32(T_CK[j, 0] * x0 + T_CK[j, 1] * y0 + T_CK[j, 2] * z0 + T_CK[j, 3])
