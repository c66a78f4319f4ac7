"""Compiled per-pixel kernels of the ``sim`` backend: keyframe matching, fusion, the current
frame's message and the depth noise, in one pass each without full-frame temporaries. They are
the backend's only implementation of these steps (``SimBackend.match``, ``._fuse``,
``._current_frame``, ``Degrader.observe``); the numpy renderings in tests/oracles/sim_perception.py
are their test oracles, in the same dtypes and operation order, and the published frames are
byte-identical (tests/perception/test_kernels.py).

A kernel takes its arrays grouped by role in tuples (keyframe, truth, frame, matches, out), not
one argument each; the groups are not a flat :class:`riskfield.protocol.kernels.Layout` workspace because
their arrays differ in dtype, come from the frame's message or the keyframe, and the outputs
leave in the next message, so there is nothing a workspace could keep from one call to the next.
"""

from __future__ import annotations

import numpy as np

from ..runtime.jit import HAVE_NUMBA, jit

if HAVE_NUMBA:

    @jit
    def match_kernel(T_CW: np.ndarray, keyframe: tuple, truth: tuple, camera: tuple, tol: tuple,
                     out: tuple) -> int:
        """Per keyframe pixel: reproject its true world point into the current camera (``T_CW``),
        accept the pixel it lands on if the true depth there agrees; fills ``out``, returns the
        number of valid matches (``SimBackend.match``).

        ``keyframe`` = (world (N, 3) float64, valid (N,), C0 (N,)); ``truth`` = the current frame's
        (points (H·W, 3) float32, valid (H·W,), confidence (H·W,) float32); ``camera`` = (h, w, fx,
        fy, cx, cy); ``tol`` = (absolute, relative to z) depth agreement; ``out`` = (idx (N,) int64,
        valid (N,) bool, Qk (N,) float64)."""
        world, kf_valid, C0 = keyframe
        truth_points, truth_valid, C_t = truth
        h, w, fx, fy, cx, cy = camera
        tol_abs, tol_rel = tol
        idx, valid, Qk = out
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

    @jit
    def fuse_kernel(T_KC: np.ndarray, frame: tuple, matches: tuple, Q_conf: float, state: tuple,
                    out: tuple) -> None:
        """One tracked frame fused into a keyframe (eq. 2 and 7–8 of ``fusion``, ``SimBackend._fuse``): the
        frame's point matched to keyframe pixel ξ, moved into the keyframe frame by ``T_KC``
        (float64, stored as float32 like ``transform_points(..., np.float32)``), averaged by
        confidence with the keyframe's; its label votes over trusted matches (valid, Qk > Q_conf).

        ``frame`` = (points (H·W, 3) float32, confidence (H·W,) float32, labels (H·W,) uint16);
        ``matches`` = (idx, valid, Qk) of :func:`match_kernel`; ``state`` = the keyframe's (X, C,
        labels, weights); ``out`` = new arrays of the same (a message built from the previous state
        keeps it) and ``trusted`` (N,) bool."""
        points, conf, labels_frame = frame
        idx, valid_match, Qk = matches
        X, C, labels, weights = state
        X_out, C_out, labels_out, weights_out, trusted = out
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

    @jit
    def incidence_kernel(points: np.ndarray, valid: np.ndarray, cos: np.ndarray) -> None:
        """|cos| of the viewing ray to the surface normal per pixel, the normal from neighbouring
        points: central differences, one-sided at the border, in float32 (the oracle's
        ``normals_from_pointmap`` then ``cos_incidence``)."""
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

    @jit
    def depth_noise_kernel(frame: tuple, draws: tuple, model: tuple, out: tuple) -> None:
        """Range noise along each pixel's ray and the confidence (``Degrader.observe``).

        ``frame`` = (points (H, W, 3) float32, valid (H, W), z (H, W) float64, |cos| of incidence
        (H, W) float32); ``draws`` = (the standard normal draw, ``exp(−z / z_scale)``), both
        computed by numpy (its random stream); ``model`` = (noise_a, noise_b, c_gain) of
        ``DegradationConfig``; ``out`` = (noisy points, confidence), float32."""
        points, valid, z, cos = frame
        normal, e = draws
        a, b, c_gain = model
        noisy, conf = out
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

    @jit
    def current_frame_kernel(T_CK: np.ndarray, keyframe: tuple, matches: tuple, Q_conf: float,
                             with_points: bool, frame: tuple) -> None:
        """The current frame's message (``SimBackend._current_frame``): over trusted matches (valid
        and Qk > Q_conf), the keyframe's fused label ``labels_k[ξ]`` written at its frame pixel
        ``idx[ξ]`` and, ``with_points``, its fused point moved into the camera by ``T_CK`` (float64,
        stored as float32 like ``transform_points(..., np.float32)``).

        ``keyframe`` = its fused (X (N, 3) float32, labels_k (N,) uint16); ``matches`` = (idx, valid,
        Qk) of :func:`match_kernel`; ``frame`` = the frame's own copies of (points (H·W, 3) float32,
        labels (H·W,) uint16), written in place: a pixel two keyframe pixels land on keeps the later
        one."""
        X, labels_k = keyframe
        idx, valid_match, Qk = matches
        points, labels = frame
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
