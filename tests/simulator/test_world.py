"""Scenarios and the world: files and built-ins load, objects move and appear, the watchdog
brakes, obstacles can be added while running."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from riskfield.protocol import ade20k
from riskfield.protocol.platforms import LIMO
from riskfield.services.simulator import shapes
from riskfield.services.simulator.mesh_io import write_ply
from riskfield.services.simulator.scenario import BUILTIN, build_scene, load_scenario
from riskfield.services.simulator.world import World

DATA = Path(__file__).parent / "data"


@pytest.mark.parametrize("name", sorted(BUILTIN))
def test_builtin_scenarios_build_and_render(name):
    w = World(name)
    f = w.render()
    assert f.valid.mean() > 0.99  # a closed room: every ray hits something
    assert w.clearance(np.array([[*w.state().position[:2], 0.1]]))[0] > 0.3  # the robot starts free


def test_teleop_scenarios_face_a_ball_or_a_dog():
    for name, label in (("teleop_ball", "ball"), ("teleop_dog", "animal")):
        w = World(name)
        f = w.render()
        h, wd = f.labels.shape
        centre = f.labels[h // 2 - 5:h // 2 + 40, wd // 2 - 5:wd // 2 + 5]
        assert (centre == ade20k.index(label)).any(), name


def test_scenario_file_with_motion_appearance_and_index_class():
    sc = load_scenario(DATA / "two_boxes.yaml")
    assert sc.name == "two_boxes" and sc.goals == [(1.5, 1.0), (1.5, -1.0)]
    scene = build_scene(sc)
    assert scene["table_1"].label == 15 and scene["dog"].moving and scene["box_1"].appear_at_s == 2.0
    w = World(sc)
    assert w.camera.width == 128
    probe = np.array([[0.0, 0.0, 0.2], [0.5, 1.0, 0.25]])
    before = w.snapshot().signed_distance(probe)
    w.advance(4.0)  # the box appeared; the dog walked 2 m to (0.5, 1.0)
    after = w.snapshot().signed_distance(probe)
    assert before[0] > 0.1 and after[0] < 0
    assert before[1] == pytest.approx(0.25, abs=1e-3) and after[1] < 0  # only the floor was near


def test_scenario_with_a_mesh_file(tmp_path):
    v, t = shapes.box(0.5, 0.5, 0.5)
    write_ply(tmp_path / "crate.ply", v, t, vertex_labels=np.ones(len(v), int))
    (tmp_path / "s.yaml").write_text("objects:\n  - mesh: crate.ply\n    names: [x, storage box]\n"
                                     "    position: [1, 1]\n")
    scene = build_scene(load_scenario(tmp_path / "s.yaml"))
    assert scene["crate_1"].label == ade20k.index("box")


@pytest.mark.parametrize("bad", [
    {"objects": [{"class": "unicorn"}]},
    {"objects": [{"class": "box", "mesh": "x.ply"}]},
    {"objects": [{"class": "box", "position": [float("nan"), 0]}]},
    {"objects": [{"class": "box", "waypoints": [[0, 0]]}]},
    {"robot": {"type": "tank"}},
    {"room": {"size": [-1, 3]}},
    {"camera": {"width": 0}},
    {"unexpected": 1},
])
def test_bad_scenarios_are_rejected(bad):
    with pytest.raises((ValidationError, ValueError, KeyError)):
        build_scene(load_scenario(bad))


def test_a_scenario_without_a_mount_has_the_limos_camera():
    mount = load_scenario({"room": {"size": [4.0, 4.0]}}).camera.camera_mount()
    assert (mount.position, mount.rpy_deg) == (LIMO.camera.position, LIMO.camera.rpy_deg)
    tilted = load_scenario({"room": {"size": [4.0, 4.0]}, "camera": {"mount": {"pitch_deg": 12}}}).camera.camera_mount()
    assert (tilted.position, tilted.rpy_deg) == (LIMO.camera.position, (0.0, 12.0, 0.0))


def test_unknown_scenario_name():
    with pytest.raises(FileNotFoundError):
        load_scenario("no_such_scenario")


def test_random_scenarios_are_deterministic():
    a, b = World("random:7"), World("random:7")
    fa, fb = a.render(), b.render()
    np.testing.assert_array_equal(fa.rgb, fb.rgb)
    assert not np.array_equal(World("random:8").render().labels, fa.labels)


def test_commands_drive_and_watchdog_brakes():
    w = World("empty", watchdog_s=0.2)
    for _ in range(20):  # 2 s at 0.5 m/s, commands every 0.1 s
        w.command(np.array([0.5, 0, 0]), np.zeros(3))
        w.advance(0.1)
    s = w.state()
    assert s.linear_velocity[0] == pytest.approx(0.5) and 0.7 < s.position[0] < 1.0
    w.advance(1.0)  # no command: after 0.2 s the robot brakes to a stop
    assert w.state().linear_velocity[0] == pytest.approx(0.0)
    assert w.watchdog_trips == 1
    x_stop = w.state().position[0]
    assert x_stop < s.position[0] + 0.5 * 0.2 + 0.5**2 / (2 * 1.5) + 1e-6
    with pytest.raises(ValueError):
        w.command(np.array([np.nan, 0, 0]), np.zeros(3))


def test_add_object_while_running_appears_now():
    w = World("empty")
    w.advance(1.0)
    name = w.add_object({"class": "person", "position": [1.0, 0.0]})
    assert w.scene[name].appear_at_s == pytest.approx(1.0)
    assert w.clearance(np.array([[1.0, 0.0, 1.0]]))[0] < 0
    f = w.render()
    assert (f.labels == ade20k.index("person")).any()
    with pytest.raises(ValidationError):
        w.add_object({"class": "person", "position": [1.0]})


def test_double_integrator_override_via_scenario_dict():
    w = World(load_scenario({"room": {"size": [4, 4]}, "robot": {"type": "double_integrator",
                                                                 "params": {"input": "acceleration"}}}))
    w.command(np.array([1.0, 0, 0]), np.zeros(3))
    w.advance(0.1)
    assert w.state().linear_velocity[0] == pytest.approx(0.1)
