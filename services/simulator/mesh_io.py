"""Labelled triangle meshes from PLY files (ascii, binary little- or big-endian).

open3d's reader drops custom properties, so this module reads PLY itself: vertex ``x, y, z``,
faces from a ``vertex_indices``/``vertex_index`` list (polygons fan-triangulated), and a
semantic label per vertex or per face from the first property named one of ``LABEL_PROPERTIES``
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

from riskfield.protocol import ade20k

from .scene import SceneObject

LABEL_PROPERTIES = ("label", "class", "category_id", "category", "semantic", "semantic_label", "class_id", "nyu40")

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}

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


@dataclass
class PlyElement:
    name: str
    count: int
    properties: list[tuple[str, str, str | None]]  # (name, value dtype, list-count dtype or None)


@dataclass
class PlyData:
    elements: dict[str, dict[str, np.ndarray | list[np.ndarray]]]


class PlyError(ValueError):
    pass


def _header(raw: bytes) -> tuple[str, list[PlyElement], int]:
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise PlyError("not a PLY file (no 'ply' magic or no end_header)")
    nl = raw.find(b"\n", end)
    body_start = len(raw) if nl < 0 else nl + 1
    fmt = ""
    elements: list[PlyElement] = []
    for line in raw[:end].decode("ascii", "replace").splitlines()[1:]:
        parts = line.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            elements.append(PlyElement(parts[1], int(parts[2]), []))
        elif parts[0] == "property":
            if not elements:
                raise PlyError("property before any element")
            if parts[1] == "list":
                elements[-1].properties.append((parts[4], _dtype(parts[3]), _dtype(parts[2])))
            else:
                elements[-1].properties.append((parts[2], _dtype(parts[1]), None))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise PlyError(f"unsupported PLY format {fmt!r}")
    return fmt, elements, body_start


def _dtype(name: str) -> str:
    try:
        return _TYPES[name]
    except KeyError:
        raise PlyError(f"unknown PLY type {name!r}") from None


def read_ply(path: str | Path) -> PlyData:
    """Every element and property of a PLY file: scalar properties as arrays, list properties
    as a list of arrays (or one 2-D array when every list has the same length)."""
    raw = Path(path).read_bytes()
    fmt, elements, pos = _header(raw)
    if fmt == "ascii":
        try:
            return _read_ascii(raw[pos:], elements)
        except (IndexError, ValueError) as exc:
            raise PlyError(f"{path}: malformed ascii body ({exc})") from None
    out: dict[str, dict[str, np.ndarray | list[np.ndarray]]] = {}
    order = "<" if fmt == "binary_little_endian" else ">"
    for el in elements:
        out[el.name], pos = _read_binary(raw, pos, el, order)
    return PlyData(out)


def _read_ascii(body: bytes, elements: list[PlyElement]) -> PlyData:
    out: dict[str, dict[str, np.ndarray | list[np.ndarray]]] = {}
    tokens = body.split()
    i = 0
    for el in elements:
        cols: dict[str, list] = {p[0]: [] for p in el.properties}
        for _ in range(el.count):
            for name, dt, count_dt in el.properties:
                if count_dt is None:
                    cols[name].append(tokens[i])
                    i += 1
                else:
                    n = int(tokens[i])
                    cols[name].append(np.array(tokens[i + 1:i + 1 + n]).astype(np.float64).astype(dt))
                    i += 1 + n
        if i > len(tokens):
            raise PlyError(f"element {el.name}: the file ends early")
        out[el.name] = {name: (np.array(cols[name]).astype(np.float64).astype(dt) if count_dt is None
                               else _stack(cols[name]))
                        for name, dt, count_dt in el.properties}
    return PlyData(out)


def _stack(rows: list[np.ndarray]) -> np.ndarray | list[np.ndarray]:
    if rows and all(len(r) == len(rows[0]) for r in rows):
        return np.stack(rows)
    return rows


def _read_binary(raw: bytes, pos: int, el: PlyElement, order: str) -> tuple[dict, int]:
    lists = [p for p in el.properties if p[2] is not None]
    if not lists:
        dt = np.dtype([(n, order + t) for n, t, _ in el.properties])
        need = dt.itemsize * el.count
        if pos + need > len(raw):
            raise PlyError(f"element {el.name}: the file ends early")
        arr = np.frombuffer(raw, dt, el.count, pos)
        return {n: arr[n].astype(arr[n].dtype.newbyteorder("=")) for n, _, _ in el.properties}, pos + need
    # Fast path: guess that every list has the length of the first row's list (triangles).
    first = _first_list_lengths(raw, pos, el, order)
    if first is not None:
        fields = []
        for n, t, ct in el.properties:
            if ct is None:
                fields.append((n, order + t))
            else:
                fields += [(n + "#n", order + ct), (n, order + t, (first[n],))]
        dt = np.dtype(fields)
        if pos + dt.itemsize * el.count <= len(raw):
            arr = np.frombuffer(raw, dt, el.count, pos)
            if all(np.all(arr[n + "#n"] == first[n]) for n, _, ct in el.properties if ct is not None):
                return ({n: arr[n].astype(arr[n].dtype.newbyteorder("=")) for n, _, _ in el.properties},
                        pos + dt.itemsize * el.count)
    # General path: row by row (mixed polygon sizes).
    cols: dict[str, list] = {p[0]: [] for p in el.properties}
    for _ in range(el.count):
        for n, t, ct in el.properties:
            if ct is None:
                d = np.dtype(order + t)
                _need(raw, pos, d.itemsize, el.name)
                cols[n].append(np.frombuffer(raw, d, 1, pos)[0])
                pos += d.itemsize
            else:
                cd, d = np.dtype(order + ct), np.dtype(order + t)
                _need(raw, pos, cd.itemsize, el.name)
                k = int(np.frombuffer(raw, cd, 1, pos)[0])
                pos += cd.itemsize
                _need(raw, pos, k * d.itemsize, el.name)
                cols[n].append(np.frombuffer(raw, d, k, pos).astype(d.newbyteorder("=")))
                pos += k * d.itemsize
    return {n: (np.array(cols[n]) if ct is None else _stack(cols[n])) for n, _, ct in el.properties}, pos


def _need(raw: bytes, pos: int, n: int, name: str) -> None:
    if pos + n > len(raw):
        raise PlyError(f"element {name}: the file ends early")


def _first_list_lengths(raw: bytes, pos: int, el: PlyElement, order: str) -> dict[str, int] | None:
    if el.count == 0:
        return None
    out = {}
    for n, t, ct in el.properties:
        if ct is None:
            pos += np.dtype(t).itemsize
        else:
            if pos + np.dtype(ct).itemsize > len(raw):
                return None
            k = int(np.frombuffer(raw, np.dtype(order + ct), 1, pos)[0])
            out[n] = k
            pos += np.dtype(ct).itemsize + k * np.dtype(t).itemsize
    return out


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
    face_prop = next((k for k in wanted if k in face and isinstance(face[k], np.ndarray) and face[k].ndim == 1), None)
    vert_prop = next((k for k in wanted if k in vert), None)
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
    """Write a triangle mesh with optional per-vertex and per-face int32 labels."""
    v = np.asarray(vertices, np.float32)
    t = np.asarray(triangles, np.int32)
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", label_name):
        raise ValueError("label_name must be an identifier")
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", f"element vertex {len(v)}",
            "property float x", "property float y", "property float z"]
    if vertex_labels is not None:
        head.append(f"property int {label_name}")
    head += [f"element face {len(t)}", "property list uchar int vertex_indices"]
    if face_labels is not None:
        head.append(f"property int {label_name}")
    head.append("end_header")
    text = ("\n".join(head) + "\n").encode("ascii")
    if binary:
        vf = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")] + ([(label_name, "<i4")] if vertex_labels is not None else [])
        va = np.zeros(len(v), vf)
        va["x"], va["y"], va["z"] = v.T
        if vertex_labels is not None:
            va[label_name] = vertex_labels
        ff = [("n", "u1"), ("i", "<i4", (3,))] + ([(label_name, "<i4")] if face_labels is not None else [])
        fa = np.zeros(len(t), ff)
        fa["n"], fa["i"] = 3, t
        if face_labels is not None:
            fa[label_name] = face_labels
        Path(path).write_bytes(text + va.tobytes() + fa.tobytes())
        return
    lines = []
    for i, p in enumerate(v):
        extra = f" {int(vertex_labels[i])}" if vertex_labels is not None else ""
        lines.append(f"{p[0]:.7g} {p[1]:.7g} {p[2]:.7g}{extra}")
    for i, f in enumerate(t):
        extra = f" {int(face_labels[i])}" if face_labels is not None else ""
        lines.append(f"3 {f[0]} {f[1]} {f[2]}{extra}")
    Path(path).write_bytes(text + ("\n".join(lines) + "\n").encode("ascii"))
