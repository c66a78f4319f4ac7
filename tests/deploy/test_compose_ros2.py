"""The ROS 2 overlay (deploy/compose.ros2.yml), checked without a Docker engine: the `ros2` profile is the
robot's router and filter, riskfield's ROS 2 bridge and zenoh-bridge-ros2dds; every command parses and
builds its settings; the bridge joins the robot router the host publishes, in the robot's namespace."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest
from deploy.test_compose import COMPOSE, ENV, PROFILES, REPO, _check_riskfield_container, _hadolint, _port, load

ROS2 = REPO / "deploy" / "compose.ros2.yml"
BRIDGE_CONFIG = REPO / "deploy" / "zenoh" / "bridge-ros2dds.json5"

pytestmark = pytest.mark.xdist_group("test_compose")


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return load([COMPOSE, ROS2], {**ENV, "RISKFIELD_ROBOT_ROUTER_PORT": "7450"}, tmp_path_factory.mktemp("ros2"))


def test_the_ros2_profile_holds_the_robot_router_filter_and_both_bridges(stack: dict[str, Any]) -> None:
    got = {n for n, s in stack.items() if "ros2" in s.get("profiles", [])}
    assert got == {"robot-router", "robot-safety-filter", "ros2-bridge", "zenoh-bridge-ros2dds"}
    assert not got & {"limo", "joystick", "camera"}  # Nav2 drives the base
    # the overlay adds a profile; the base file's profiles are unchanged
    for profile, expected in PROFILES.items():
        assert {n for n, s in stack.items() if profile in s.get("profiles", [])} == expected, profile
    for name in got - {"robot-router"}:
        assert stack[name]["depends_on"] == ["robot-router"], name
        assert stack[name]["restart"] == "unless-stopped", name


def test_riskfield_containers_of_the_profile_are_valid_commands(stack: dict[str, Any],
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("robot-safety-filter", "ros2-bridge"):
        assert _check_riskfield_container(name, stack[name], monkeypatch) == "settings", name
    bridge = stack["ros2-bridge"]
    assert bridge["environment"]["RISKFIELD_CONNECT"] == "tcp/robot-router:7447"
    assert bridge["build"]["dockerfile"] == "deploy/Dockerfile.ros2"
    assert bridge["build"]["args"]["ROBOT_IMAGE"] == stack["robot-safety-filter"]["image"]
    assert "namespace=limo7" in bridge["command"] and "healthcheck" in bridge


def test_zenoh_bridge_joins_the_published_robot_router_in_the_robots_namespace(stack: dict[str, Any]) -> None:
    svc = stack["zenoh-bridge-ros2dds"]
    assert svc["image"].startswith("eclipse/zenoh-bridge-ros2dds:")
    assert svc["network_mode"] == "host"  # DDS discovery is on the host's network
    cmd = svc["command"]
    assert cmd[cmd.index("-e") + 1] == "tcp/127.0.0.1:7450"
    assert ("127.0.0.1", "7450", "7447") in [_port(p) for p in stack["robot-router"]["ports"]]
    assert cmd[cmd.index("--namespace") + 1] == "/limo7"
    (mount,) = svc["volumes"]  # "host:container:ro" as docker-compose 1.29 normalises it
    source, target, mode = mount.split(":")
    assert Path(source) == BRIDGE_CONFIG and target == cmd[cmd.index("-c") + 1] and mode == "ro"


def test_bridge_config_routes_the_topics_riskfields_bridge_uses() -> None:
    text = re.sub(r"//[^\n]*", "", BRIDGE_CONFIG.read_text())  # JSON5 comments; the rest is JSON here
    text = re.sub(r"(\w+):", r'"\1":', text).replace(",\n    }", "\n    }")
    text = re.sub(r",(\s*[}\]])", r"\1", text)
    cfg = json.loads(text)
    allow = cfg["plugins"]["ros2dds"]["allow"]
    assert {"/cmd_vel_smoothed", "/odom", "/tf", "/tf_static"} <= set(allow["publishers"])
    assert {"/cmd_vel_riskfield", "/riskfield/costmap", "/diagnostics"} <= set(allow["subscribers"])


def test_ros2_dockerfile_passes_hadolint() -> None:
    path = REPO / "deploy" / "Dockerfile.ros2"
    proc = subprocess.run([_hadolint(), "--no-color", "--failure-threshold", "info", str(path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "requirements.py ros2" in path.read_text()
