"""Loader of ScanNet++ scenes for the safety benchmark (for users who have the dataset).

A ScanNet++ scene folder ``data/<scene_id>/scans/`` holds ``mesh_aligned_0.05.ply`` (the
decimated, z-up aligned mesh) and ``segments_anno.json`` whose ``segGroups`` list annotated
objects: ``label`` (free text) and ``segments`` (indices of the mesh's vertices that belong
to the object). Each object becomes one ``SceneObject`` made of the triangles whose three
vertices all belong to it; every other triangle (walls, floor, unannotated clutter) goes into
one ``structure`` object with per-triangle labels (floor/ceiling/wall by their annotation,
``wall`` otherwise). ScanNet++ labels are mapped onto ADE20K classes by the shipped table of
ScanNet++'s 100 benchmark classes (``scannetpp_labels``), then by name and synonyms
(``simulator.mesh_io``); an unknown label becomes ``box`` (a generic low-risk obstacle).

Scans are open surfaces: the objects are marked non-watertight, so the benchmark measures
clearance with the unsigned distance to the mesh.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from riskfield.experiments.scannetpp_labels import scannetpp_to_ade20k
from riskfield.protocol import ade20k
from riskfield.services.simulator.mesh_io import ade20k_index_of
from riskfield.services.simulator.scene import SceneObject


def ade20k_label(name: str) -> int:
    """ADE20K index of a ScanNet++ label: the shipped benchmark-class table, else the simulator's
    name/synonym table; ``box`` when nothing matches."""

    known = scannetpp_to_ade20k(name)
    return known if known is not None else ade20k_index_of(name, unknown="box")


def load_scene(folder: str | Path):
    """The objects of one ScanNet++ scene (``folder`` is ``data/<id>`` or its ``scans``)."""
    import open3d as o3d


    folder = Path(folder)
    scans = folder / "scans" if (folder / "scans").is_dir() else folder
    ply, anno = scans / "mesh_aligned_0.05.ply", scans / "segments_anno.json"
    for p in (ply, anno):
        if not p.is_file():
            raise FileNotFoundError(f"{p} is missing: expected a ScanNet++ scene folder")
    mesh = o3d.io.read_triangle_mesh(str(ply))
    verts = np.asarray(mesh.vertices, np.float32)
    tris = np.asarray(mesh.triangles, np.int64)
    if len(tris) == 0:
        raise ValueError(f"{ply} has no triangles")
    groups = json.loads(anno.read_text()).get("segGroups", [])
    owner = np.full(len(verts), -1, np.int64)
    labels: list[int] = []
    names: list[str] = []
    for g in groups:
        idx = np.asarray(g.get("segments", []), np.int64)
        idx = idx[(idx >= 0) & (idx < len(verts))]
        owner[idx] = len(labels)
        labels.append(ade20k_label(str(g.get("label", ""))))
        names.append(f"{g.get('label', 'object')}_{g.get('objectId', g.get('id', len(names)))}")
    tri_owner = owner[tris]
    same = (tri_owner[:, 0] == tri_owner[:, 1]) & (tri_owner[:, 1] == tri_owner[:, 2]) & (tri_owner[:, 0] >= 0)
    objects = []
    structural = {ade20k.index(n) for n in ("wall", "floor", "ceiling")}
    rest = ~same
    tri_labels = np.full(len(tris), ade20k.index("wall"), np.uint16)
    for k, (label, name) in enumerate(zip(labels, names, strict=True)):
        mine = same & (tri_owner[:, 0] == k)
        if not mine.any():
            continue
        if label in structural:  # floors and walls stay in the structure mesh, labelled
            tri_labels[mine] = label
            rest |= mine
            continue
        sub, remap = _submesh(verts, tris[mine])
        objects.append(SceneObject(name.replace(" ", "_"), label, (sub, remap), watertight=False))
    if rest.any():
        sub, remap = _submesh(verts, tris[rest])
        objects.append(SceneObject("structure", ade20k.index("wall"), (sub, remap),
                                   triangle_labels=tri_labels[rest], watertight=False))
    return objects


def _submesh(verts: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used, inverse = np.unique(tris.reshape(-1), return_inverse=True)
    return verts[used].copy(), inverse.reshape(-1, 3).astype(np.uint32)


def scannetpp_folders(path: str | Path) -> list[Path]:
    """``path`` itself when it is one scene (``<id>`` or ``<id>/scans``), else its scene sub-folders."""
    path = Path(path)
    if (path / "scans").is_dir() or (path / "mesh_aligned_0.05.ply").is_file():
        return [path]
    found = sorted(p for p in path.iterdir() if p.is_dir() and (p / "scans").is_dir()) if path.is_dir() else []
    if not found:
        raise FileNotFoundError(f"{path} is neither a ScanNet++ scene nor a folder of scenes")
    return found
