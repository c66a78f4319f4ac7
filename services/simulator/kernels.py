"""The renderer's per-pixel work in compiled passes over open3d's raw ray-cast output: the rays
packed for open3d (``pack_rays_kernel``) and each hit shaded into depth, pointmap, label, normal,
object index and colour (``shade_kernel``), without full-frame temporaries between the camera stamp
and the image. They are the renderer's only implementation (``camera.Renderer``); the numpy
rendering in tests/oracles/sim_camera.py is their test oracle (tests/simulator/test_render_kernel.py
checks the bytes).

``shade_kernel``'s arrays come grouped by role in tuples (hits, camera, scene, out), not one argument each; not a
flat :class:`riskfield.protocol.kernels.Layout` workspace, because they differ in dtype, the hits are
open3d's and the outputs leave in the frame, so there is nothing a workspace could keep.
"""
from __future__ import annotations

import numpy as np

from ..runtime.jit import HAVE_NUMBA, jit

if HAVE_NUMBA:

    @jit
    def shade_kernel(hits: tuple, camera: tuple, scene: tuple, shading: tuple, out: tuple) -> None:
        """Per ray k (flattened pixels): depth, camera-frame point ``rays·depth``, label, world normal,
        object index (zero / ``no_label`` / −1 where nothing was hit within ``max_depth``) and the
        Lambert-shaded class colour ``lut[label]·shade + ½`` as uint8.

        ``hits`` = open3d's (t_hit, geometry_ids, primitive_ids, primitive_normals); ``camera`` =
        (camera-frame rays, world directions, 1 / |ray|) per pixel; ``scene`` = the snapshot's
        (offsets, object_index, triangle_labels) and the colour ``lut``; ``shading`` = (max_depth,
        no_label, ambient0, ambient1): shade = ambient0 + ambient1·light; ``out`` = (depth, points,
        labels, normals, rgb, object)."""
        t_hit, geometry_ids, primitive_ids, primitive_normals = hits
        rays, dirs, inv_len = camera
        offsets, object_index, triangle_labels, lut = scene
        max_depth, no_label, ambient0, ambient1 = shading
        depth, points, labels, normals, rgb, obj = out
        zero = np.float32(0.0)
        one = np.float32(1.0)
        md = np.float32(max_depth)
        a0, a1 = np.float32(ambient0), np.float32(ambient1)
        w_head, w_sky, half = np.float32(0.8), np.float32(0.2), np.float32(0.5)
        for k in range(t_hit.shape[0]):
            t = t_hit[k]
            if t <= md:  # inf (no hit) and NaN fail this too
                g = geometry_ids[k]
                lab = triangle_labels[offsets[g] + primitive_ids[k]]
                n0, n1, n2 = primitive_normals[k, 0], primitive_normals[k, 1], primitive_normals[k, 2]
                obj[k] = object_index[g]
                d = t
            else:
                lab = np.uint16(no_label)
                n0 = n1 = n2 = zero
                obj[k] = -1
                d = zero
            depth[k] = d
            points[k, 0] = rays[k, 0] * d
            points[k, 1] = rays[k, 1] * d
            points[k, 2] = rays[k, 2] * d
            labels[k] = lab
            normals[k, 0], normals[k, 1], normals[k, 2] = n0, n1, n2
            n_dot_d = n0 * dirs[k, 0] + n1 * dirs[k, 1] + n2 * dirs[k, 2]
            lambert = abs(n_dot_d) * inv_len[k]
            sky = min(max(n2, zero), one)
            shade = a0 + a1 * min(w_head * lambert + w_sky * sky, one)
            for c in range(3):
                rgb[k, c] = np.uint8(lut[lab, c] * shade + half)

    @jit
    def pack_rays_kernel(R: np.ndarray, origin: np.ndarray, rays_cam: np.ndarray, out: np.ndarray) -> None:
        """open3d's (N, 6) ray rows: the camera origin and each camera-frame ray rotated into the
        world by ``R`` (float32 sums ``R[i,0]·v0 + R[i,1]·v1 + R[i,2]·v2``, in that order)."""
        for k in range(rays_cam.shape[0]):
            v0, v1, v2 = rays_cam[k, 0], rays_cam[k, 1], rays_cam[k, 2]
            out[k, 0], out[k, 1], out[k, 2] = origin[0], origin[1], origin[2]
            for i in range(3):
                out[k, 3 + i] = R[i, 0] * v0 + R[i, 1] * v1 + R[i, 2] * v2
