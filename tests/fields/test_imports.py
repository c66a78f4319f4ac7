"""The field API, the numpy-only geometry and the external planner example work without scipy,
open3d, numba or torch (a robot-level install, a planner's machine): with those four unimportable,
they import and a grid query answers (interpreted); with everything installed, they load neither
open3d nor torch."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "esdf_planner.py"
HEAVY = ("scipy", "open3d", "numba", "torch")

USE = (
    "import sys, runpy\n"
    "import numpy as np\n"
    "import riskfield.services.fields, riskfield.services.geometry.shapes, riskfield.services.geometry.camera\n"
    f"runpy.run_path({str(EXAMPLE)!r}, run_name='not_main')\n"
    "from riskfield.services.fields import EsdfField\n"
    "f = EsdfField(np.arange(16.0).reshape(4, 4, 1), (0.0, 0.0, 0.0), 1.0)\n"
    "s = f.query(np.array([[1.5, 1.0, 0.0]]))\n"
    "assert abs(s.distance[0] - 7.0) < 1e-12 and bool(s.inside[0]), s\n"
    f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
)

BLOCK = (
    "import importlib.abc, sys\n"
    "class Block(importlib.abc.MetaPathFinder):\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    f"        if name.split('.')[0] in {HEAVY!r}:\n"
    "            raise ImportError(f'No module named {name!r} (blocked by the test)', name=name)\n"
    "sys.meta_path.insert(0, Block())\n"
)


def run(code: str) -> str:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          check=True).stdout.strip()


def test_fields_shapes_and_the_planner_example_work_without_the_heavy_packages() -> None:
    assert run(BLOCK + USE) == "[]"


def test_with_everything_installed_they_load_neither_open3d_nor_torch() -> None:
    loaded = run(USE)
    assert "open3d" not in loaded and "torch" not in loaded, loaded
