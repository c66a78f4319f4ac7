"""Watertight primitive meshes for scene objects, as ``(vertices float32 Nx3, triangles uint32 Mx3)``.

Every shape is closed and consistently oriented (outward normals) because the ground-truth
signed distance (open3d ``compute_signed_distance``) decides inside/outside by counting ray
crossings: an open or self-intersecting mesh would flip the sign. Composite shapes (a person)
are therefore built as *one* closed surface (a capsule), never as overlapping parts.

Local frame of every shape: origin at the centre of its footprint on the floor, z up, x forward
(the direction a moving object faces), so placing an object is a yaw and a floor position.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

Mesh = tuple[np.ndarray, np.ndarray]


def _arrays(m: o3d.geometry.TriangleMesh) -> Mesh:
    return np.asarray(m.vertices, np.float32).copy(), np.asarray(m.triangles, np.uint32).copy()


def box(sx: float, sy: float, sz: float) -> Mesh:
    """An axis-aligned box ``sx × sy × sz`` standing on the floor (12 triangles)."""
    v, t = _arrays(o3d.geometry.TriangleMesh.create_box(sx, sy, sz))
    v -= np.array([sx / 2, sy / 2, 0.0], np.float32)
    return v, t


def slab(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> Mesh:
    """A box between two corners, in the frame the corners are given in (walls, floor)."""
    lo_, hi_ = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    size = hi_ - lo_
    if np.any(size <= 0):
        raise ValueError(f"slab needs hi > lo on every axis, got {lo} and {hi}")
    v, t = _arrays(o3d.geometry.TriangleMesh.create_box(*size))
    return (v + lo_.astype(np.float32)).astype(np.float32), t


def ellipsoid(rx: float, ry: float, rz: float, resolution: int = 16) -> Mesh:
    """An ellipsoid with semi-axes ``rx, ry, rz`` resting on the floor (a ball when equal)."""
    v, t = _arrays(o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=resolution))
    v *= np.array([rx, ry, rz], np.float32)
    v[:, 2] += rz
    return v, t


def sphere(radius: float, resolution: int = 16) -> Mesh:
    return ellipsoid(radius, radius, radius, resolution)


def cylinder(radius: float, height: float, resolution: int = 24) -> Mesh:
    """An upright cylinder standing on the floor."""
    v, t = _arrays(o3d.geometry.TriangleMesh.create_cylinder(radius=radius, height=height, resolution=resolution))
    v[:, 2] += height / 2
    return v, t


def capsule(radius: float, height: float, resolution: int = 16) -> Mesh:
    """An upright capsule of total ``height`` (≥ 2·radius): one closed surface, made by pulling
    the hemispheres of a sphere apart (the sphere's equator ring goes with the upper half, and
    the band joining it to the next ring down becomes the straight section)."""
    if height < 2 * radius:
        raise ValueError(f"capsule height {height} is below its diameter {2 * radius}")
    if resolution % 2:
        resolution += 1  # an even resolution puts a vertex ring exactly on the equator
    v, t = _arrays(o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=resolution))
    half = (height - 2 * radius) / 2
    upper = v[:, 2] > -1e-6 * radius
    v[upper, 2] += half
    v[~upper, 2] -= half
    v[:, 2] += height / 2
    return v, t


def person(height: float = 1.7, radius: float = 0.22) -> Mesh:
    """A standing person as a capsule (shoulder-width radius)."""
    return capsule(radius, height)


def animal(length: float = 0.7, width: float = 0.3, height: float = 0.5) -> Mesh:
    """A dog-sized animal as an ellipsoid, long axis along x (the way it walks)."""
    return ellipsoid(length / 2, width / 2, height / 2)


def transform(mesh: Mesh, T: np.ndarray) -> Mesh:
    """The mesh with its vertices moved by the 4x4 rigid transform ``T``."""
    v, t = mesh
    R, p = T[:3, :3].astype(np.float32), T[:3, 3].astype(np.float32)
    return (v @ R.T + p).astype(np.float32), t
