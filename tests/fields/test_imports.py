"""The field API and the numpy-only geometry import without scipy, open3d or numba, so a
robot-level install and the external planner example can use them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "esdf_planner.py"


def test_fields_and_shapes_import_numpy_only() -> None:
    code = (
        "import sys, runpy\n"
        "import riskfield.services.fields, riskfield.services.geometry.shapes, riskfield.services.geometry.camera\n"
        f"runpy.run_path({str(EXAMPLE)!r}, run_name='not_main')\n"
        "print(sorted(m for m in ('scipy', 'open3d', 'numba', 'torch') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"
