"""Labelled triangle meshes from PLY files (ascii, binary little- or big-endian).

open3d's reader drops custom properties, so the file is read with ``plyfile``, which keeps every
element and property: vertex ``x, y, z``, faces from a ``vertex_indices``/``vertex_index`` list
(polygons fan-triangulated), and a semantic label per vertex or per face from the first scalar
property named one of ``LABEL_PROPERTIES``
(``label`` as in ScanNet/ScanNet++ semantic meshes, ``class``, ``category_id``, …). Per-vertex
labels become per-face labels by majority of the face's vertices.

Dataset labels are mapped to ADE20K indices by a caller-supplied map (dict or function of the
raw label), or by class names (``names[raw]``) through ``ade20k_index_of`` — exact ADE20K names
plus the usual dataset synonyms (couch → sofa, tv → television receiver, dog → animal, …).

Scanned meshes are rarely watertight: the loaded object is flagged so, and its ground truth
should use the unsigned ``distance`` (see ``scene``).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import plyfile

from riskfield.protocol import ade20k

from .scene import SceneObject

LABEL_PROPERTIES = ("label", "class", "category_id", "category", "semantic", "semantic_label", "class_id", "nyu40")

#: Dataset class names (lower case) that are not ADE20K names → the ADE20K name they mean.
SYNONYMS: dict[str, str] = {
    "couch": "sofa", "bookshelf": "bookcase", "bookshelves": "bookcase", "tv": "television receiver",
    "television": "television receiver", "trash can": "ashcan", "trash bin": "ashcan", "garbage bin": "ashcan",
    "window": "windowpane", "picture": "painting", "office chair": "swivel chair", "kitchen cabinet": "cabinet",
    "kitchen cabinets": "cabinet", "cabinets": "cabinet", "dog": "animal", "cat": "animal", "pet": "animal",
    "blinds": "blind", "washing machine": "washer", "carpet": "rug", "floor mat": "rug", "mat": "rug",
    "pillar": "column", "heater": "radiator", "kitchen counter": "counter", "doorframe": "door",
    "door frame": "door", "whiteboard": "bulletin board", "monitor screen": "monitor", "fridge": "refrigerator",
    "potted plant": "plant", "plant pot": "pot", "storage box": "box", "cardboard box": "box", "crate": "box",
    "people": "person", "human": "person", "coffee-table": "coffee table", "nightstand": "chest of drawers",
    "dresser": "chest of drawers", "wardrobe closet": "wardrobe", "closet": "wardrobe", "toy": "plaything",
    "sports ball": "ball", "soccer ball": "ball", "stair": "stairs", "staircase": "stairway", "ceiling light": "light",
    "lamp shade": "lamp", "shower curtain": "curtain", "tv stand": "cabinet", "bin": "ashcan", "basket": "basket",
    "backpack": "bag", "suitcase": "bag", "computer monitor": "monitor", "laptop": "computer", "keyboard": "computer",
}


def ade20k_index_of(name: str, unknown: str | None = "box") -> int:
    """ADE20K index of a dataset class name (exact name, then synonym, then plural 's' dropped);
    ``unknown`` is used for a name that matches nothing (``None``: raise ``KeyError``)."""
    key = name.strip().lower().replace("_", " ")
    for cand in (key, SYNONYMS.get(key), key[:-1] if key.endswith("s") else None):
        if cand and cand in ade20k.INDEX:
            return ade20k.INDEX[cand]
        if cand and cand in SYNONYMS:
            return ade20k.INDEX[SYNONYMS[cand]]
    if unknown is None:
        raise KeyError(f"class name {name!r} has no ADE20K equivalent")
    return ade20k.index(unknown)


class PlyError(ValueError):
    pass


@dataclass
class PlyData:
    """Every element of a PLY file: its scalar properties as arrays, its list properties as one
    2-D array when every list has the same length, else as a list of arrays (``lists`` names them)."""

    elements: dict[str, dict[str, np.ndarray | list[np.ndarray]]]
    lists: dict[str, frozenset[str]]


def _ply_read(path: Path, known_list_len: dict[str, dict[str, int]]) -> plyfile.PlyData:
    try:
        return plyfile.PlyData.read(str(path), known_list_len=known_list_len)
    except (plyfile.PlyParseError, ValueError, TypeError, KeyError, EOFError) as exc:
        raise PlyError(f"{path}: {exc}") from None


def read_ply(path: str | Path) -> PlyData:
    """Every element and property of a PLY file (ascii, binary little- or big-endian), read by
    ``plyfile``. Binary faces are first read as triangles, memory-mapped in one pass
    (``PlyData.read``'s ``known_list_len``, which checks every list's length); a file with other
    polygons is then read list by list."""
    path = Path(path)
    triangles = {"face": {"vertex_indices": 3, "vertex_index": 3}}
    try:
        ply = _ply_read(path, triangles)
    except PlyError:
        ply = _ply_read(path, {})
    elements: dict[str, dict[str, np.ndarray | list[np.ndarray]]] = {}
    lists: dict[str, frozenset[str]] = {}
    for el in ply.elements:
        listed = frozenset(p.name for p in el.properties if isinstance(p, plyfile.PlyListProperty))
        data = el.data
        elements[el.name] = {p.name: (_stack(list(data[p.name])) if p.name in listed and data[p.name].ndim == 1
                                      else np.array(data[p.name]))
                             for p in el.properties}
        lists[el.name] = listed
    return PlyData(elements, lists)


def _stack(rows: list[np.ndarray]) -> np.ndarray | list[np.ndarray]:
    if rows and all(len(r) == len(rows[0]) for r in rows):
        return np.stack(rows)
    return [np.asarray(r) for r in rows]


def _triangulate(faces: np.ndarray | list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Triangles and, for each, the index of the polygon it came from (fan triangulation)."""
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        k = faces.shape[1]
        if k == 3:
            return faces.astype(np.int64), np.arange(len(faces))
        polys = list(faces)
    else:
        polys = list(faces)
    tris, src = [], []
    for i, f in enumerate(polys):
        for j in range(1, len(f) - 1):
            tris.append((f[0], f[j], f[j + 1]))
            src.append(i)
    return np.asarray(tris, np.int64).reshape(-1, 3), np.asarray(src, np.int64)


@dataclass
class LabelledMesh:
    vertices: np.ndarray  # (N, 3) float32
    triangles: np.ndarray  # (M, 3) uint32
    triangle_labels: np.ndarray  # (M,) uint16 ADE20K
    raw_labels: np.ndarray  # (M,) the dataset's own label per triangle

    def watertight(self) -> bool:
        return is_closed(self.triangles)

    def to_object(self, name: str = "mesh", pose: np.ndarray | None = None) -> SceneObject:
        labels = self.triangle_labels
        main = int(np.bincount(labels).argmax()) if len(labels) else 0
        return SceneObject(name, main, (self.vertices, self.triangles), np.eye(4) if pose is None else pose,
                           triangle_labels=labels, watertight=self.watertight())


def is_closed(triangles: np.ndarray) -> bool:
    """Whether every edge is shared by exactly two triangles (a closed 2-manifold surface)."""
    if len(triangles) == 0:
        return False
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]).astype(np.int64)
    e.sort(axis=1)
    _, counts = np.unique(e[:, 0] * (int(e.max()) + 1) + e[:, 1], return_counts=True)
    return bool(np.all(counts == 2))


LabelMap = Mapping[int, int] | Callable[[int], int]


def _vote(tri_vertex_labels: np.ndarray) -> np.ndarray:
    a, b, c = tri_vertex_labels.T
    return np.where((b == c) & (a != b), b, a)


def load_labelled_ply(path: str | Path, label_map: LabelMap | None = None, names: Sequence[str] | None = None,
                      unknown: str | None = "box", label_property: str | None = None) -> LabelledMesh:
    """A triangle mesh with an ADE20K label per triangle.

    Raw labels map to ADE20K through ``label_map`` (dict or function), else through
    ``names[raw]`` and ``ade20k_index_of``, else they are taken as ADE20K indices already. A mesh
    without any label property gets ``unknown`` everywhere."""
    ply = read_ply(path)
    if "vertex" not in ply.elements or "face" not in ply.elements:
        raise PlyError(f"{path}: a labelled mesh needs vertex and face elements")
    vert, face = ply.elements["vertex"], ply.elements["face"]
    try:
        xyz = np.stack([np.asarray(vert[k], np.float64) for k in ("x", "y", "z")], axis=1)
    except KeyError:
        raise PlyError(f"{path}: vertex element lacks x, y or z") from None
    fkey = next((k for k in ("vertex_indices", "vertex_index") if k in face), None)
    if fkey is None:
        raise PlyError(f"{path}: face element lacks a vertex_indices list")
    tris, src = _triangulate(face[fkey])
    if len(tris) and (tris.min() < 0 or tris.max() >= len(xyz)):
        raise PlyError(f"{path}: a face indexes a vertex that does not exist")
    if not np.isfinite(xyz).all():
        raise PlyError(f"{path}: non-finite vertex coordinates")
    wanted = (label_property,) if label_property else LABEL_PROPERTIES
    face_prop = next((k for k in wanted if k in face and k not in ply.lists['face']), None)
    vert_prop = next((k for k in wanted if k in vert and k not in ply.lists['vertex']), None)
    if face_prop is not None:
        raw = np.asarray(face[face_prop])[src]
    elif vert_prop is not None:
        raw = _vote(np.asarray(vert[vert_prop])[tris])
    else:
        raw = None
    if raw is None:
        labels = np.full(len(tris), ade20k.index(unknown or "box"), np.uint16)
        raw = np.zeros(len(tris), np.int64)
    else:
        labels = _map_labels(raw, label_map, names, unknown)
    return LabelledMesh(xyz.astype(np.float32), tris.astype(np.uint32), labels, raw)


def _map_labels(raw: np.ndarray, label_map: LabelMap | None, names: Sequence[str] | None, unknown: str | None
                ) -> np.ndarray:
    uniq, inverse = np.unique(raw, return_inverse=True)
    mapped = np.empty(len(uniq), np.int64)
    for i, r in enumerate(uniq.tolist()):
        if label_map is not None:
            mapped[i] = label_map(r) if callable(label_map) else label_map.get(r, ade20k_index_of("", unknown))
        elif names is not None:
            name = names[int(r)] if 0 <= int(r) < len(names) else ""
            mapped[i] = ade20k_index_of(name, unknown)
        else:
            mapped[i] = int(r) if 0 <= int(r) < ade20k.NUM_CLASSES else ade20k_index_of("", unknown)
    if mapped.min() < 0 or mapped.max() >= ade20k.NUM_CLASSES:
        raise PlyError("the label map produced an index outside ADE20K's 0..149")
    return mapped[inverse.reshape(-1)].astype(np.uint16)


def write_ply(path: str | Path, vertices: np.ndarray, triangles: np.ndarray, *, vertex_labels: np.ndarray | None = None,
              face_labels: np.ndarray | None = None, binary: bool = True, label_name: str = "label") -> None:
    """Write a triangle mesh with optional per-vertex and per-face int32 labels (``plyfile``; the
    faces as a ``uchar``-counted ``vertex_indices`` list, as ScanNet's meshes have them)."""
    v = np.asarray(vertices, np.float32).reshape(-1, 3)
    t = np.asarray(triangles, np.int32).reshape(-1, 3)
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", label_name):
        raise ValueError("label_name must be an identifier")
    va = np.zeros(len(v), [("x", "f4"), ("y", "f4"), ("z", "f4")]
                  + ([(label_name, "i4")] if vertex_labels is not None else []))
    va["x"], va["y"], va["z"] = v.T
    if vertex_labels is not None:
        va[label_name] = vertex_labels
    fa = np.zeros(len(t), [("vertex_indices", "i4", (3,))] + ([(label_name, "i4")] if face_labels is not None else []))
    fa["vertex_indices"] = t
    if face_labels is not None:
        fa[label_name] = face_labels
    elements = [plyfile.PlyElement.describe(va, "vertex"),
                plyfile.PlyElement.describe(fa, "face", len_types={"vertex_indices": "u1"})]
    plyfile.PlyData(elements, text=not binary, byte_order="<").write(str(path))
