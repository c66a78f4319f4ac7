"""The simulator node over a real Zenoh router, in its own process."""

from __future__ import annotations

import signal
from pathlib import Path

import msgpack
import numpy as np
import pytest

from riskfield.protocol import (
    CERTAIN_CONFIDENCE,
    Image,
    NodeStatus,
    PerceptionFrame,
    RobotState,
    VelocityCommand,
    ade20k,
)
from riskfield.services.perception.node import decode_image
from riskfield.testing import (
    Collector,
    ServiceProcess,
    client_session,
    hostile_payloads,
    put,
    wait_alive,
    wait_until,
)

SCENARIO = str(Path(__file__).parent / "data" / "two_boxes.yaml")


def _args(robot: str) -> list[str]:
    return ["--robot", robot, "--set", f"scenario={SCENARIO}", "--set", "status_period_s=0.3",
            "--set", "camera_hz=10", "--set", "state_hz=50"]


def test_simulator_publishes_state_image_truth_and_obeys_commands(router_endpoint):
    robot = "t_sim_cmd"
    with ServiceProcess("simulator", router_endpoint, _args(robot)) as sim, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/simulator"), sim.output
        states = Collector(s, f"rf/{robot}/state", RobotState)
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        truths = Collector(s, f"rf/{robot}/sim/truth", PerceptionFrame)
        images.wait(3, 20)
        truths.wait(3, 20)
        img = images.items[-2]
        truth = next(t for t in truths.items if t.header.stamp_ns == img.header.stamp_ns)
        # JPEG by default: what crosses the link; perception decodes it to the same size.
        assert img.width == 128 and img.height == 96 and img.encoding == "jpeg"
        assert decode_image(img).data.shape == (96, 128, 3)
        # every 2nd pixel (truth_stride), as float32 depth + the strided camera's intrinsics
        assert truth.points is None and truth.pixels == (48, 64) and np.all(truth.confidence == CERTAIN_CONFIDENCE)
        cx, cy = truth.intrinsics[2:]
        assert truth.depth.dtype == np.float32 and np.allclose((cx, cy), (127 / 2 / 2, 95 / 2 / 2))
        assert np.all(truth.depth > 0) and set(np.unique(truth.labels)) <= set(range(ade20k.NUM_CLASSES))
        start = states.wait(1, 10)[-1].position
        forward = VelocityCommand(linear=(0.4, 0, 0), angular=(0, 0, 0), source="test")
        # A command stream at ~20 Hz (the period is the scenario: one command would expire in the
        # watchdog) until the robot is under way.
        assert wait_until(lambda: (put(s, f"rf/{robot}/cmd/safe", forward),
                                   states.items[-1].linear_velocity[0] > 0.3
                                   and states.items[-1].position[0] > start[0] + 0.3)[1], 10.0, period_s=0.05), \
            states.items[-1]
        # Watchdog: no command for 0.2 s → the robot brakes to a stop.
        assert wait_until(lambda: abs(states.items[-1].linear_velocity[0]) < 1e-9, 5)
        assert sim.stop(signal.SIGTERM) == 0, sim.output
        for c in (states, images, truths):
            c.close()


def test_simulator_survives_hostile_input_and_spawns_objects(router_endpoint):
    robot = "t_sim_fuzz"
    with ServiceProcess("simulator", router_endpoint, _args(robot)) as sim, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/simulator"), sim.output
        status = Collector(s, f"rf/{robot}/status/simulator", NodeStatus)
        states = Collector(s, f"rf/{robot}/state", RobotState)
        truths = Collector(s, f"rf/{robot}/sim/truth", PerceptionFrame)
        valid = VelocityCommand(linear=(0.3, 0, 0), angular=(0, 0, 0.2), source="fuzz")
        hostile = hostile_payloads(valid, 300, seed=3)
        for p in hostile:
            put(s, f"rf/{robot}/cmd/safe", p)
        rng = np.random.default_rng(0)
        bad_spawns = [rng.bytes(int(n)) for n in rng.integers(0, 64, 20)] + [
            msgpack.packb({"class": "unicorn"}), msgpack.packb({"class": "box", "position": [float("nan"), 0]}),
            msgpack.packb([1, 2, 3]), b'{"class": "box", "size": [0, 1, 1]}']
        for p in bad_spawns:
            put(s, f"rf/{robot}/sim/spawn", p)
        # cmd/safe is a latest-value queue: whatever was not overwritten was decoded and rejected.
        def all_seen() -> bool:
            st = status.items[-1] if status.items else None
            return bool(st and st.received.get("cmd/safe") == len(hostile)
                        and st.invalid["cmd/safe"] == len(hostile) - st.dropped["cmd/safe"] > 0)

        assert wait_until(all_seen, 20), status.items[-1] if status.items else sim.output
        assert wait_until(lambda: status.items[-1].extra.get("spawn_invalid", 0) == len(bad_spawns), 20), \
            status.items[-1]
        # Still serving: a valid command moves it, a valid spawn appears in the ground truth.
        x0 = states.wait(1, 10)[-1].position[0]
        assert wait_until(lambda: (put(s, f"rf/{robot}/cmd/safe", valid), states.items[-1].position[0] != x0)[1],
                          10.0, period_s=0.05), states.items[-1]
        assert all(np.isfinite(st.position).all() for st in states.items)
        truths.clear()
        put(s, f"rf/{robot}/sim/spawn", msgpack.packb({"class": "person", "name": "intruder",
                                                       "position": [-1.0, 0.0]}))
        assert wait_until(lambda: any((t.labels == ade20k.index("person")).any() for t in list(truths.items)), 10)
        assert status.items[-1].errors == 0
        assert sim.alive()
        assert sim.stop() == 0
        assert "rejected a spawn request" in sim.output and "spawned intruder" in sim.output
        for c in (status, states, truths):
            c.close()


def test_simulator_publishes_depth_stamped_like_the_image(router_endpoint):
    from riskfield.protocol import DepthImage

    robot = "t_sim_depth"
    args = [*_args(robot), "--set", "publish_depth=true"]
    with ServiceProcess("simulator", router_endpoint, args) as sim, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/simulator"), sim.output
        depths = Collector(s, f"rf/{robot}/camera/depth", DepthImage)
        truths = Collector(s, f"rf/{robot}/sim/truth", PerceptionFrame)
        depths.wait(3, 20)
        truths.wait(3, 20)
        # the newest depth whose truth arrived too (the truth collector subscribed a little later)
        truth_stamps = {t.header.stamp_ns: t for t in truths.items}
        d = next(d for d in reversed(depths.items) if d.header.stamp_ns in truth_stamps)
        truth = truth_stamps[d.header.stamp_ns]
        assert d.depth.shape == (96, 128) and d.header.frame_id == "camera"
        np.testing.assert_allclose(d.depth[::2, ::2], truth.depth)  # the truth: every 2nd pixel's z
        # the intrinsics back-project the depth onto the true pointmap, that of the truth's strided camera too
        u, v = np.meshgrid(np.arange(128), np.arange(96))
        points = truth.pointmap()
        np.testing.assert_allclose(((u - d.cx) / d.fx * d.depth)[::2, ::2], points[..., 0], atol=1e-5)
        np.testing.assert_allclose(((v - d.cy) / d.fy * d.depth)[::2, ::2], points[..., 1], atol=1e-5)
        assert sim.stop(signal.SIGTERM) == 0, sim.output
        depths.close()
        truths.close()


def test_simulator_publishes_actors_stamped_like_the_image_and_starts_over_on_reset(router_endpoint):
    from riskfield.protocol import SimActors

    robot = "t_sim_actors"
    with ServiceProcess("simulator", router_endpoint, _args(robot)) as sim, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/simulator"), sim.output
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        actors = Collector(s, f"rf/{robot}/sim/actors", SimActors)
        states = Collector(s, f"rf/{robot}/state", RobotState)
        relocalised = Collector(s, f"rf/{robot}/state/relocalise", RobotState)
        put(s, f"rf/{robot}/sim/spawn", msgpack.packb({"class": "person", "name": "walker", "position": [-0.5, -1.5],
                                                       "waypoints": [[-0.5, -1.5], [-0.5, 1.5]], "speed": 1.2}))
        assert wait_until(lambda: any("walker" in [a.name for a in m.actors] for m in list(actors.items)), 20)
        images.wait(len(images.items) + 3, 20)
        stamps = {m.header.stamp_ns: m for m in actors.items}
        paired = [stamps[i.header.stamp_ns] for i in images.items if i.header.stamp_ns in stamps]
        assert len(paired) >= 2  # every image has the actors of its instant, same stamp
        walking = [next(a for a in m.actors if a.name == "walker") for m in paired
                   if "walker" in [a.name for a in m.actors]]
        assert [a.name for a in paired[-1].actors] == ["dog", "walker"]
        w0, w1 = walking[0], walking[-1]
        assert w1.position[1] > w0.position[1] and w1.velocity == pytest.approx((0.0, 1.2, 0.0))
        assert w0.radius == pytest.approx(0.22, abs=1e-3)
        # the walker moved as far as its speed allows between the two images' stamps
        dt = (paired[-1].header.stamp_ns - paired[0].header.stamp_ns) / 1e9
        assert w1.position[1] - w0.position[1] <= 1.2 * dt + 0.15
        # Drive away, then start over: the robot is back at its start, the spawned walker gone.
        forward = VelocityCommand(linear=(0.4, 0, 0), angular=(0, 0, 0), source="test")
        assert wait_until(lambda: (put(s, f"rf/{robot}/cmd/safe", forward),
                                   states.items[-1].position[0] > -1.2)[1], 10.0, period_s=0.05)
        # No command in flight when it resets (cmd/safe and sim/reset are separate subscriptions: a
        # late forward would drive the new world): the watchdog has stopped the robot first.
        assert wait_until(lambda: abs(states.items[-1].linear_velocity[0]) < 1e-9, 10)
        put(s, f"rf/{robot}/sim/reset", b"")
        put(s, f"rf/{robot}/sim/reset", b"\xff\xfe not a scenario")
        assert wait_until(lambda: abs(states.items[-1].position[0] + 1.5) < 1e-9, 10)
        # the jump back was announced (the filter and the mapping refuse an unannounced one)
        assert len(relocalised.items) == 1 and abs(relocalised.items[0].position[0] + 1.5) < 1e-9
        n = len(actors.items)
        assert wait_until(lambda: len(actors.items) > n + 1, 10)
        assert [a.name for a in actors.items[-1].actors] == ["dog"]
        assert sim.alive()
        assert sim.stop() == 0
        assert "rejected a reset request" in sim.output
        for c in (images, actors, states, relocalised):
            c.close()
