"""The safety benchmark's protocol on a tiny scene: roll-outs, maps, and the CLI end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from riskfield.experiments.safety_benchmark import (
    BenchConfig,
    barriers_differ,
    build_pointcloud,
    camera_poses,
    filter_safe_control,
    gt_perception,
    make_case,
    rollout,
    variants,
    zero_margins,
)
from riskfield.experiments.sampling import Pair
from riskfield.protocol import RiskConfig, ade20k
from riskfield.services.fields import AnalyticField
from riskfield.services.geometry.shapes import Sphere
from riskfield.services.geometry.transforms import pose_matrix
from riskfield.services.navigator.clf import PointMassCLF
from riskfield.services.simulator import procedural, shapes
from riskfield.services.simulator.scene import SceneObject

CFG = BenchConfig(robot_radius=0.15)
CLF = PointMassCLF(CFG.k_p, CFG.k_d, CFG.v_max, CFG.a_max)


@pytest.fixture(scope="module")
def case():
    ball = SceneObject("ball_1", ade20k.index("ball"), shapes.sphere(0.3, resolution=32),
                       pose_matrix(0.0, 0.0, 0.2))
    return make_case("tiny", [*procedural.room(4.0, 4.0, 2.5), ball], RiskConfig())


def test_case_excludes_floor_and_ceiling_from_ground_truth(case):
    names = {o.name for o in case.obstacles.objects}
    assert "floor" not in names and "ceiling" not in names and "ball_1" in names
    # Just above the floor is far from every obstacle; the ball's centre is inside it.
    d = case.clearance(np.array([[1.0, 1.0, 0.02], [0.0, 0.0, 0.5]]))
    assert d[0] > 0.5 and d[1] == pytest.approx(-0.3, abs=0.01)
    assert [t.name for t in case.targets] == ["ball_1"] and case.targets[0].group == "low"


def test_free_path_reaches_the_goal(case):
    pair = Pair(0, "ball_1", "low", np.array([-1.5, 1.2, 0.5]), np.array([1.5, 1.2, 0.5]))
    r = rollout("m", pair, AnalyticField(Sphere([0.0, 0.0, 0.5], 0.3)), filter_safe_control(CFG), CLF, CFG, case)
    assert r.progress > 0.97
    assert r.clearance.min() > 0.3  # 0.5 m from the walls at the ends, minus the radius
    assert np.all(r.filter_times > 0)


def test_exact_field_keeps_clearance_through_a_blocked_path(case):
    # Straight through the ball (centre at z 0.5): the filter must steer around or stop.
    pair = Pair(0, "ball_1", "low", np.array([-1.5, 0.05, 0.5]), np.array([1.5, 0.05, 0.5]))
    exact = AnalyticField(Sphere([0.0, 0.0, 0.5], 0.3))
    r = rollout("m", pair, exact, filter_safe_control(CFG), CLF, CFG, case)
    assert r.clearance.min() > -0.02  # HOCBF in discrete time: at most a small overshoot
    assert r.reached > 0.3  # it did approach
    # With the filter off, the same pair goes straight through the ball.
    unfiltered = rollout("off", pair, exact, lambda f, p, v, u: u, CLF, CFG, case)
    assert unfiltered.clearance.min() < -0.3


def test_pointcloud_map_from_renders_matches_ground_truth(case):
    from riskfield.services.geometry.camera import PinholeCamera
    from riskfield.services.simulator.camera import Renderer

    perceive = gt_perception(Renderer(PinholeCamera.from_fov(128, 96, 90.0)))
    stream = [perceive(case.scene.at(0.0), T) for T in camera_poses(case, 12)]
    built = build_pointcloud(stream, budget_s=60.0, voxel=0.05, z_range=(case.lo[2], case.hi[2]))
    assert built.frames == 12 and built.field.size > 1000
    pts = np.array([[0.0, -0.7, 0.5], [0.6, 0.0, 0.5], [1.5, 1.5, 1.2]])
    est = built.field.query(pts).distance
    gt = case.clearance(pts)
    assert np.abs(est[:2] - gt[:2]).max() < 0.06  # near the ball, seen from both sides
    # Floor points were removed: high above the floor the nearest point is not the floor.
    assert built.field.query(np.array([[0.0, -1.5, 0.1]])).distance[0] > 0.3
    starved = build_pointcloud(stream, budget_s=0.0, voxel=0.05)
    assert starved.frames == 0 and starved.field.size == 0


def test_zero_margins_keeps_groups_and_gains():
    r = zero_margins(RiskConfig())
    assert [g.margin for g in r.groups] == [0.0, 0.0, 0.0]
    assert [g.alpha1 for g in r.groups] == [g.alpha1 for g in RiskConfig().groups]
    assert RiskConfig().groups[0].margin == 0.15  # the original is untouched


def test_the_other_barrier_row_runs_only_where_it_can_differ():
    """The braking barrier is the HOCBF below its speed floor a_b/k₂ (1.05 / 1.5 = 0.7 m/s with the
    bench's gains): at v_max 0.5 m/s a `hocbf` row would repeat the default's roll-outs exactly."""
    assert not barriers_differ(BenchConfig())
    assert [v.suffix for v in variants(BenchConfig())] == ["no extra margin",
                                                           "paper's HOCBF (trilinear), no extra margin"]
    fast = BenchConfig(v_max=1.0)
    assert barriers_differ(fast) and "hocbf barrier, no extra margin" in [v.suffix for v in variants(fast)]
    assert not barriers_differ(BenchConfig(v_max=0.69)) and barriers_differ(BenchConfig(v_max=0.71))


@pytest.mark.slow
def test_bench_cli_end_to_end(tmp_path):
    from typer.testing import CliRunner

    from riskfield.experiments.benches.safety import app

    res = CliRunner().invoke(app, ["--trajectories", "6", "--scenes", "1", "--frames", "9", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    s = json.loads((tmp_path / "summary.json").read_text())
    extra = [f"{m}, {v.suffix}" for m in ("Ours (ESDF)", "Ours (Semantic ESDF)") for v in variants(BenchConfig())]
    assert len(extra) == 4 and s["trajectories"] == 6 and len(s["per_trajectory"]) == 6 * (3 + 4)
    assert set(s["table2"]) == {"Point cloud", "Ours (ESDF)", "Ours (Semantic ESDF)"}
    # Margins in the open: every method with its extra margin beyond the robot radius.
    assert set(s["methods"]) == {*s["table2"], *extra} == {*s["table2"], *s["no_extra_margin"]}
    assert s["methods"]["Ours (ESDF)"]["margin_m"] == pytest.approx(0.025 + 0.5 * 0.05)  # δ = v_max T, ½ voxel
    # The same rule on the cloud: δ and half its downsampling cell (half the ESDF's voxel).
    assert s["methods"]["Point cloud"]["margin_m"] == pytest.approx(0.025 + 0.5 * 0.025)
    for name in extra:
        assert s["methods"][name]["margin_m"] == 0.0 == s["no_extra_margin"][name]["margin_m"]
    assert {s["methods"][f"Ours (ESDF), {v.suffix}"]["barrier"] for v in variants(BenchConfig())} == {"braking",
                                                                                                      "hocbf"}
    assert s["methods"]["Ours (ESDF), paper's HOCBF (trilinear), no extra margin"]["interpolation"] == "trilinear"
    for name, row in s["table2"].items():
        assert row["margin_m"] == s["methods"][name]["margin_m"]
    for row in s["table2"].values():
        assert 0.0 <= row["progress"] <= 1.0 and 0.0 <= row["mp_collision_rate"] <= 1.0
        assert row["computation_time_s"] > 0  # measured; its size is the bench's report, not a test
    assert {m["method"] for m in s["maps"]} == set(s["table2"])
    md = (tmp_path / "tables.md").read_text()
    assert "Table II" in md and "Table III" in md and "Full-run safety" in md
    for traj in s["per_trajectory"]:  # every trajectory keeps its full-run minimum clearance
        assert isinstance(traj["min_clearance"], float) and traj["relaxed_steps"] >= 0
    for name, row in s["table2"].items():
        assert 0.0 <= row["collision_rate"] <= 1.0 and 0.0 <= row["relaxed_fraction"] <= 1.0
        assert row["min_clearance_m"] == min(t["min_clearance"] for t in s["per_trajectory"] if t["method"] == name)
    # The tables carry this run's numbers (the first row of a method is the reproduction's).
    for name, row in s["table2"].items():
        line = next(ln for ln in md.splitlines() if ln.startswith(f"| {name} |"))
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert float(cells[2]) == pytest.approx(row["progress"], abs=1e-3), line
        assert float(cells[4]) == pytest.approx(row["mp_collision_rate"], abs=1e-3), line
    for name, row in s["no_extra_margin"].items():  # the full-run table: margin, then collision rate
        line = next(ln for ln in md.splitlines() if ln.startswith(f"| {name} |"))
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert float(cells[1]) == 0.0 and float(cells[2]) == pytest.approx(row["collision_rate"], abs=1e-3), line
    assert (tmp_path / "safety_methods.png").stat().st_size > 1000


def test_the_stream_sees_the_top_of_a_tall_person():
    """From 1.3 m with the 31° tilt no frame sees above ≈ 1.7 m: without the stream's high frames
    the top of a 1.94 m person is missing from every map and the ESDF reads +0.09 m where the
    robot's body is 0.09 m inside the head. The high frames see it: 5 cm above the top, the
    ESDF's distance is within a voxel of the truth."""
    from riskfield.experiments.safety_benchmark import ESDF, build_esdf_maps
    from riskfield.services.geometry.camera import PinholeCamera
    from riskfield.services.simulator.camera import Renderer

    person = SceneObject("person_1", ade20k.index("person"), shapes.person(1.94), pose_matrix(0.6, -0.4, 0.0))
    tall = make_case("tall", [*procedural.room(4.0, 4.0, 2.5), person], RiskConfig())
    cfg = BenchConfig(image=(128, 96), frames=12)
    heights = sorted({round(float(T[2, 3]), 2) for T in camera_poses(tall, cfg.frames)})
    assert heights == [1.3, 2.1]
    perceive = gt_perception(Renderer(PinholeCamera.from_fov(*cfg.image, 90.0)))
    stream = [perceive(tall.scene.at(0.0), T) for T in camera_poses(tall, cfg.frames)]
    esdf = {b.method: b for b in build_esdf_maps(tall, stream, 60.0, cfg, RiskConfig())}[ESDF].field
    top = person.world_mesh(0.0)[0].max(axis=0)[2]
    probe = np.array([[0.6, -0.4, top + 0.05]])
    assert esdf.query(probe).distance[0] < tall.clearance(probe)[0] + cfg.voxel


def test_ends_keep_clear_of_every_class_margin():
    assert CFG.end_clearance >= max(g.margin for g in RiskConfig().groups) + 0.05
