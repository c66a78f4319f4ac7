"""Libraries the project uses instead of its own code, and test-only libraries out of the
runtime: PLY through ``plyfile``; ``edt`` only for the mapping's test oracle and bench."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import plyfile

from riskfield.services.simulator.mesh_io import load_labelled_ply, write_ply

ROOT = Path(__file__).resolve().parents[2]


def extras() -> dict[str, list[str]]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]


def _names(reqs: list[str]) -> set[str]:
    return {r.split(";")[0].split("[")[0].split(">")[0].split("=")[0].split("<")[0].strip().lower() for r in reqs}


def test_a_mapping_node_imports_no_edt():
    """The node and its core as a mapping node loads them, and the default ESDF path run once."""
    code = (
        "import sys\n"
        "import riskfield.services.mapping.node\n"
        "from riskfield.services.mapping.config import MapperConfig\n"
        "from riskfield.services.mapping.esdf_integrator import EsdfIntegrator\n"
        "import numpy as np\n"
        "integrator = EsdfIntegrator.of(MapperConfig(half_extent=(0.5, 0.5, 0.5)))\n"
        "print('edt' in sys.modules)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["False"]


def test_edt_is_a_dev_dependency_not_a_mapping_one():
    from riskfield.services.runtime.service import MODULE_EXTRAS

    assert "edt" not in _names(extras()["mapping"])
    assert "edt" in _names(extras()["dev"])
    assert MODULE_EXTRAS["edt"] == "dev"


def test_ply_files_are_plyfiles():
    """mesh_io reads and writes through plyfile, declared by the simulator's extra."""
    from riskfield.services.simulator import mesh_io

    assert "plyfile" in _names(extras()["sim"])
    assert getattr(mesh_io, "plyfile", None) is plyfile
    assert not hasattr(mesh_io, "_read_binary") and not hasattr(mesh_io, "_header")  # no hand-written parser


def test_a_mesh_plyfile_writes_loads_and_ours_reads_in_plyfile(tmp_path):
    """Files from other tools (here plyfile itself: a quad with uint counts and a per-face ushort
    class) load, and what write_ply writes is a PLY that plyfile reads back."""
    vertices = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [("x", "f8"), ("y", "f8"), ("z", "f8")])
    faces = np.array([([0, 1, 2, 3], 15)], [("vertex_indices", "u4", (4,)), ("class", "u2")])
    data = plyfile.PlyData([plyfile.PlyElement.describe(vertices, "vertex"),
                            plyfile.PlyElement.describe(faces, "face", len_types={"vertex_indices": "u4"})],
                           byte_order="<")
    data.write(str(tmp_path / "quad.ply"))
    mesh = load_labelled_ply(tmp_path / "quad.ply")
    assert mesh.triangles.tolist() == [[0, 1, 2], [0, 2, 3]] and mesh.triangle_labels.tolist() == [15, 15]

    write_ply(tmp_path / "ours.ply", mesh.vertices, mesh.triangles, face_labels=np.array([7, 9]))
    back = plyfile.PlyData.read(str(tmp_path / "ours.ply"))
    assert back["face"]["label"].tolist() == [7, 9]
    assert np.stack(back["face"]["vertex_indices"]).tolist() == [[0, 1, 2], [0, 2, 3]]


def test_the_perception_extra_installs_what_perception_imports():
    """Each package of the extra is imported by the perception service (no stray scipy)."""
    import_name = {"pillow": "PIL", "torch": "torch"}
    sources = " ".join(p.read_text() for p in (ROOT / "services" / "perception").glob("*.py"))
    for package in _names(extras()["perception"]):
        module = import_name.get(package, package)
        imported = f"import {module}" in sources or f"from {module}" in sources
        required = f'_require(("{module}",))' in sources  # the GPU backends' importlib helper
        assert imported or required, f"{package}: nothing in services/perception imports it"
