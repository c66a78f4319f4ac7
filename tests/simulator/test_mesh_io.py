"""Labelled PLY: our reader against our writer (ascii and binary), per-vertex and per-face
labels, polygons, big-endian files, label maps, and broken files."""

from __future__ import annotations

import numpy as np
import pytest

from oracles.sim_camera import cast
from riskfield.protocol import ade20k
from riskfield.services.simulator import shapes
from riskfield.services.simulator.mesh_io import (
    PlyError,
    ade20k_index_of,
    is_closed,
    load_labelled_ply,
    read_ply,
    write_ply,
)
from riskfield.services.simulator.scene import Scene


@pytest.mark.parametrize("binary", [True, False])
def test_round_trip_with_face_labels(tmp_path, binary):
    v, t = shapes.box(1, 2, 3)
    labels = np.arange(len(t)) % 3 + 10
    p = tmp_path / "m.ply"
    write_ply(p, v, t, face_labels=labels, binary=binary)
    m = load_labelled_ply(p)
    np.testing.assert_allclose(m.vertices, v, atol=1e-6)
    np.testing.assert_array_equal(m.triangles, t)
    np.testing.assert_array_equal(m.triangle_labels, labels)
    assert m.watertight()


@pytest.mark.parametrize("binary", [True, False])
def test_vertex_labels_vote_per_face_and_map_through_names(tmp_path, binary):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    t = np.array([[0, 1, 2], [1, 3, 2]])
    vl = np.array([1, 1, 2, 2])  # face 0: two 1s → 1; face 1: 1, 2, 2 → 2
    p = tmp_path / "v.ply"
    write_ply(p, v, t, vertex_labels=vl, binary=binary)
    names = ["unlabelled", "couch", "dog"]
    m = load_labelled_ply(p, names=names)
    assert m.triangle_labels.tolist() == [ade20k.index("sofa"), ade20k.index("animal")]
    assert m.raw_labels.tolist() == [1, 2]
    m2 = load_labelled_ply(p, label_map={1: 15, 2: 19})
    assert m2.triangle_labels.tolist() == [15, 19]
    m3 = load_labelled_ply(p, label_map=lambda raw: 100 + raw)
    assert m3.triangle_labels.tolist() == [101, 102]
    assert not m.watertight()


def test_polygons_big_endian_and_extra_elements(tmp_path):
    header = (b"ply\nformat binary_big_endian 1.0\ncomment quad and triangle\nelement vertex 5\n"
              b"property double x\nproperty double y\nproperty double z\nproperty uchar red\n"
              b"element face 2\nproperty list uchar uint vertex_index\nproperty ushort class\n"
              b"element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n")
    verts = b"".join(np.array([x, y, 0.0], ">f8").tobytes() + bytes([7])
                     for x, y in [(0, 0), (1, 0), (1, 1), (0, 1), (2, 0)])
    faces = (bytes([4]) + np.array([0, 1, 2, 3], ">u4").tobytes() + np.array([15], ">u2").tobytes()
             + bytes([3]) + np.array([1, 4, 2], ">u4").tobytes() + np.array([19], ">u2").tobytes())
    edge = np.array([0, 1], ">i4").tobytes()
    p = tmp_path / "q.ply"
    p.write_bytes(header + verts + faces + edge)
    data = read_ply(p)
    assert data.elements["vertex"]["red"].tolist() == [7] * 5
    m = load_labelled_ply(p)
    assert m.triangles.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2]]
    assert m.triangle_labels.tolist() == [15, 15, 19]


def test_ascii_quads(tmp_path):
    text = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "property int label\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0 7\n1 0 0 7\n1 1 0 7\n0 1 0 7\n4 0 1 2 3\n")
    p = tmp_path / "a.ply"
    p.write_text(text)
    m = load_labelled_ply(p)
    assert len(m.triangles) == 2 and m.triangle_labels.tolist() == [7, 7]


def test_loaded_mesh_becomes_a_scene_object_with_per_triangle_labels(tmp_path):
    v, t = shapes.box(1, 1, 1)
    labels = np.where(np.arange(len(t)) < 6, 15, 7)
    p = tmp_path / "b.ply"
    write_ply(p, v, t, face_labels=labels)
    obj = load_labelled_ply(p).to_object("scan")
    assert obj.watertight and obj.triangle_labels is not None
    scene = Scene([obj])
    assert scene.signed_distance(np.array([[0, 0, 0.5]]))[0] == pytest.approx(-0.5, abs=1e-5)
    hits = cast(scene.at(), np.array([[0, 0, 5.0], [0, 0, -5.0], [5, 0, 0.5], [-5, 0, 0.5]]),
                np.array([[0, 0, -1.0], [0, 0, 1.0], [-1, 0, 0], [1, 0, 0]]))
    assert set(hits.label.tolist()) <= {15, 7} and len(set(hits.label.tolist())) == 2


def test_label_names():
    assert ade20k_index_of("Chair") == 19
    assert ade20k_index_of("kitchen_cabinets") == 10
    assert ade20k_index_of("TV") == ade20k.index("television receiver")
    assert ade20k_index_of("tables") == 15
    assert ade20k_index_of("flux capacitor") == ade20k.index("box")
    with pytest.raises(KeyError):
        ade20k_index_of("flux capacitor", unknown=None)


@pytest.mark.parametrize("payload", [
    b"not a ply at all",
    b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n",
    b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    b"property float z\nend_header\n\x00\x00",
    b"ply\nformat ebcdic 1.0\nend_header\n",
    b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quaternion x\nend_header\n1\n",
])
def test_broken_files_raise_ply_error(tmp_path, payload):
    p = tmp_path / "bad.ply"
    p.write_bytes(payload)
    with pytest.raises(PlyError):
        load_labelled_ply(p)


def test_face_index_out_of_range(tmp_path):
    p = tmp_path / "oob.ply"
    write_ply(p, np.zeros((3, 3)), np.array([[0, 1, 5]]), face_labels=np.array([1]))
    with pytest.raises(PlyError):
        load_labelled_ply(p)


def test_is_closed():
    _, t = shapes.box(1, 1, 1)
    assert is_closed(t) and not is_closed(t[:-1]) and not is_closed(t[:0])
