"""The simulated camera's rendering in numpy, as a test oracle of the compiled shading pass
(``services/simulator/kernels.py``, ``pack_rays_kernel`` and ``shade_kernel``): first hits of the
rays (``cast``) and the renderer's depth, pointmap, labels, normals, object index and shaded colour
(``render``), in the kernels' float32/float64 steps and order, so their outputs are byte-identical
(tests/simulator/test_render_kernel.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskfield.services.simulator.camera import _LUT, Render, Renderer
from riskfield.services.simulator.scene import NO_LABEL, Snapshot


@dataclass
class Hits:
    """First hit of every ray (leading shape of the rays): ``t`` (inf where nothing was hit),
    world ``normal`` (zero where nothing), ``label`` (``NO_LABEL`` where nothing) and
    ``object`` (index into ``Scene.objects``, -1 where nothing)."""

    t: np.ndarray
    normal: np.ndarray
    label: np.ndarray
    object: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return np.isfinite(self.t)


def cast(snapshot: Snapshot, origins: np.ndarray, directions: np.ndarray) -> Hits:
    """First hits of rays ``origins + t·directions`` (both ``(..., 3)``, broadcastable): ``t`` in
    units of the direction's length, the label of the triangle hit (per object, or per triangle
    for loaded meshes) and the index of the object hit."""
    shape = np.broadcast_shapes(np.shape(origins), np.shape(directions))[:-1]
    if snapshot.empty:
        return Hits(np.full(shape, np.inf, np.float32), np.zeros((*shape, 3), np.float32),
                    np.full(shape, NO_LABEL, np.uint16), np.full(shape, -1, np.int32))
    rays = np.empty((*shape, 6), np.float32)
    rays[..., :3] = np.asarray(origins, np.float32)
    rays[..., 3:] = np.asarray(directions, np.float32)
    out = snapshot.cast_packed(rays.reshape(-1, 6))
    t_hit = out["t_hit"]
    hit = np.isfinite(t_hit)
    # Misses carry INVALID_ID: route them to the sentinel entries at the end of the tables.
    gid = np.where(hit, out["geometry_ids"], len(snapshot.object_index) - 1)
    flat = np.where(hit, snapshot.offsets[gid] + out["primitive_ids"], snapshot.n_triangles)
    normal = out["primitive_normals"]
    normal[~hit] = 0.0
    return Hits(t_hit.reshape(shape), normal.reshape(*shape, 3), snapshot.triangle_labels[flat].reshape(shape),
                snapshot.object_index[gid].reshape(shape))


def rotate(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` (..., 3) rotated by ``R``: float32 sums in ``pack_rays_kernel``'s order."""
    out = np.empty_like(v)
    for i in range(3):
        out[..., i] = R[i, 0] * v[..., 0] + R[i, 1] * v[..., 1] + R[i, 2] * v[..., 2]
    return out


def render(renderer: Renderer, snapshot: Snapshot, T_WC: np.ndarray) -> Render:
    """``renderer.render(snapshot, T_WC)`` in numpy: one ray per pixel from the camera pose."""
    T_WC = np.asarray(T_WC, np.float64)
    R = T_WC[:3, :3].astype(np.float32)
    rays = renderer.camera.rays()
    inv_len = (1.0 / np.linalg.norm(rays, axis=-1)).astype(np.float32)
    dirs = rotate(R, rays)
    hits = cast(snapshot, T_WC[:3, 3].astype(np.float32), dirs)
    ok = hits.t <= renderer.max_depth  # inf (no hit) fails this too
    depth = np.where(ok, hits.t, np.float32(0.0))
    points = rays * depth[..., None]
    labels = np.where(ok, hits.label, NO_LABEL)
    normals = hits.normal  # zero where nothing was hit
    normals[~ok] = 0.0  # and beyond max_depth
    # Lambert: head-light |n·view| (both faces lit) plus light from above.
    n_dot_d = normals[..., 0] * dirs[..., 0] + normals[..., 1] * dirs[..., 1] + normals[..., 2] * dirs[..., 2]
    lambert = np.abs(n_dot_d) * inv_len
    sky = np.clip(normals[..., 2], 0.0, 1.0)
    ambient = renderer.ambient
    shade = (255.0 * ambient) + (255.0 * (1.0 - ambient)) * np.minimum(0.8 * lambert + 0.2 * sky, 1.0)
    rgb = (_LUT[labels] * shade[..., None] + 0.5).astype(np.uint8)  # black where nothing was hit
    return Render(rgb=rgb, depth=depth, points=points, labels=labels, normals=normals,
                  object=np.where(ok, hits.object, -1).astype(np.int32), T_WC=T_WC)
