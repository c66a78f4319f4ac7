"""Pieces of the safety benchmark: object-centric sampling, the ScanNet++ loader and the
paper-shaped tables (the point-cloud baseline field is tested in ``tests/fields``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from riskfield.experiments.benches.filter import _cases, paced_steps_us, scene, variant
from riskfield.experiments.sampling import PairRule, sample_pairs, targets_from_boxes
from riskfield.experiments.tables import table2, table3, write_json
from riskfield.protocol import RiskConfig, ade20k
from riskfield.services.fields import to_esdf
from riskfield.services.safety_filter.filter import SafetyFilter


def boxes():
    idx = ade20k.index
    return [
        ("wall", idx("wall"), np.array([-3.0, -3, 0]), np.array([3.0, -2.9, 2.5])),
        ("floor", idx("floor"), np.array([-3.0, -3, -0.1]), np.array([3.0, 3, 0])),
        ("person", idx("person"), np.array([-0.2, -0.2, 0]), np.array([0.2, 0.2, 1.7])),
        ("chair", idx("chair"), np.array([1.0, 1.0, 0]), np.array([1.4, 1.4, 0.9])),
        ("ball", idx("ball"), np.array([-1.2, 1.0, 0]), np.array([-1.0, 1.2, 0.2])),
    ]


def test_targets_exclude_structure_and_carry_risk_groups():
    targets = targets_from_boxes(boxes(), RiskConfig())
    assert [(t.name, t.group) for t in targets] == [("person", "high"), ("chair", "mid"), ("ball", "low")]
    np.testing.assert_allclose(targets[0].centre, [0.0, 0.0])
    assert targets[0].radius == pytest.approx(np.hypot(0.4, 0.4) / 2)


def test_pairs_straddle_their_target_and_are_balanced():
    targets = targets_from_boxes(boxes(), RiskConfig())
    centres = {t.name: t for t in targets}

    def clearance(p):  # distance to the target boxes' footprint circles, as a stand-in for the mesh
        return np.min([np.linalg.norm(p[:, :2] - t.centre, axis=1) - t.radius for t in targets], axis=0)

    rng = np.random.default_rng(0)
    rule = PairRule(0.1, np.array([-2.9, -2.9, 0]), np.array([3.0, 3.0, 2.5]))
    pairs = sample_pairs(targets, 30, clearance, rng, rule)
    assert len(pairs) == 30
    assert [p.pair for p in pairs] == list(range(30))
    counts = {g: sum(p.group == g for p in pairs) for g in ("high", "mid", "low")}
    assert counts == {"high": 10, "mid": 10, "low": 10}
    for p in pairs:
        t = centres[p.target]
        a, b = p.start[:2] - t.centre, p.goal[:2] - t.centre
        assert a @ b < 0  # opposite sides
        assert clearance(np.stack([p.start, p.goal])).min() > 0.2 - 1e-9
        # the segment passes within the footprint circle's neighbourhood
        d = b - a
        s = np.clip(-(a @ d) / (d @ d), 0, 1)
        assert np.linalg.norm(a + s * d) <= t.radius * 0.5 + 1e-9
        assert p.start[2] == p.goal[2]


def test_tables_are_paper_shaped(tmp_path):
    row = dict(computation_time_s=1e-4, progress=0.7, mp_clearance_m=0.1, mp_collision_rate=0.2, n=10)
    t2 = table2({"Point cloud": row, "Ours (ESDF)": row, "Ours (Semantic ESDF)": row}, 30)
    assert t2.count("\n| Ours (ESDF) |") == 2  # ours and the paper's
    assert "| 1.00e-04 | 0.700 | 0.100 | 0.200 |" in t2
    t3 = table3({g: {"esdf": row, "semantic": row} for g in ("high", "mid", "low")}, 30)
    assert "| High | 10 | 0.700 | 0.100 | 0.200 | 0.700 | 0.100 | 0.200 |" in t3
    assert "| High | 0.669 | 0.128 | 0.146 | 0.534 | 0.134 | 0.116 |" in t3
    write_json(tmp_path / "s.json", {"a": float("nan"), "b": np.arange(2), "c": np.float32(1.5)})
    assert json.loads((tmp_path / "s.json").read_text()) == {"a": None, "b": [0, 1], "c": 1.5}


def test_scannetpp_loader(tmp_path):
    import open3d as o3d

    from riskfield.experiments.scannetpp import ade20k_label, load_scene

    scans = tmp_path / "scene0" / "scans"
    scans.mkdir(parents=True)
    floor = o3d.geometry.TriangleMesh.create_box(4, 4, 0.01).translate((-2, -2, -0.01))
    chair = o3d.geometry.TriangleMesh.create_box(0.5, 0.5, 0.9).translate((0.5, 0.5, 0))
    mesh = floor + chair
    o3d.io.write_triangle_mesh(str(scans / "mesh_aligned_0.05.ply"), mesh)
    nf = len(floor.vertices)
    anno = {"segGroups": [
        {"id": 0, "objectId": 0, "label": "floor", "segments": list(range(nf))},
        {"id": 1, "objectId": 1, "label": "office chair", "segments": list(range(nf, nf + len(chair.vertices)))},
    ]}
    (scans / "segments_anno.json").write_text(json.dumps(anno))
    objects = load_scene(tmp_path / "scene0")
    by_name = {o.name: o for o in objects}
    assert set(by_name) == {"office_chair_1", "structure"}
    assert by_name["office_chair_1"].label == ade20k.index("swivel chair")
    assert len(by_name["office_chair_1"].mesh[1]) == 12
    assert set(by_name["structure"].triangle_labels.tolist()) == {ade20k.index("floor")}
    assert not by_name["structure"].watertight
    assert ade20k_label("Couch") == ade20k.index("sofa")
    assert ade20k_label("mystery thing") == ade20k.index("box")
    with pytest.raises(FileNotFoundError):
        load_scene(tmp_path)


def test_paced_filter_steps_are_timed_one_by_one() -> None:
    """``riskfield bench filter``'s paced table: every step and every wake-up probe is timed."""
    grid = to_esdf(scene(True), [-1.0, -1.0, 0.0], [3.0, 2.0, 0.0], 0.05, planar=True)
    filt = SafetyFilter(variant("unicycle", "after"))
    cases = _cases(filt, grid, True, 5, np.random.default_rng(1))
    r = paced_steps_us(filt, grid, cases, 0.001)
    assert set(r) == {"step_p50", "step_p99", "wake_p50", "wake_p99", "wake_back_to_back_p50"}
    assert all(np.isfinite(v) and v > 0 for v in r.values())
    assert r["step_p99"] >= r["step_p50"] and r["wake_p99"] >= r["wake_p50"]


def test_bench_mapping_runs_end_to_end_on_a_small_map(tmp_path) -> None:
    """`riskfield bench mapping` at a toy size, without the node: every row is measured and the
    summary written (a renamed timing key would break its last line, after all the work)."""
    import json

    from typer.testing import CliRunner

    from riskfield.experiments.benches import mapping

    out = tmp_path / "bm"
    result = CliRunner().invoke(mapping.app, ["--node-seconds", "0", "--repeat", "2", "--frames", "4", "--width", "128",
                                              "--height", "96", "--out", str(out)])
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["results"]["objects"]["median"] > 0 and summary["results"]["esdf3d_exact"]["median"] > 0
