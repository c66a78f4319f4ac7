"""The safety-filter node sees a person walking at it on ``map/objects``, over Zenoh.

The test is the robot and the mapper: every fifth control period it publishes an ESDF with the
person where they are and the matching ``TrackedObjects`` entry (stamped like the ESDF, as the
mapper does), then each period the state and a reference whose ``source`` names the period;
it waits for the node's first ``cmd/safe`` answering *that* reference (event-based: the
command's source carries it; the state went out before it, so that step used it), drives the
LIMO with it, and walks the person on. The same scenario through the filter core without
``map/objects`` is the static barrier.
"""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from riskfield.protocol import (
    Header,
    NodeStatus,
    RobotState,
    SafetyStatus,
    TrackedObject,
    TrackedObjects,
    VelocityCommand,
)
from riskfield.services.fields import AnalyticField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Sphere
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.settings import FilterSettings
from riskfield.services.safety_filter.state import FilterState
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_until

GROUPS = ["high", "mid", "low"]
PERSON, MARGIN, SPEED = 0.22, 0.15, 1.2
STEPS = 120


def esdf(x: float):
    # The mapper's view: the person's cylinder inflated by the high group's margin.
    field = AnalyticField(Sphere((x, 0.0, 0.0), PERSON + MARGIN, label=1, planar=True), groups=GROUPS)
    return to_esdf(field, [-3.0, -1.5, 0.0], [4.5, 1.5, 0.0], 0.05, planar=True)


def state_msg(s: FilterState) -> RobotState:
    yaw = s.yaw
    return RobotState(position=tuple(s.position.tolist()), orientation=(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
                      linear_velocity=tuple(s.velocity.tolist()), angular_velocity=tuple(s.angular_velocity.tolist()))


def scenario(step) -> dict:
    """Drive the LIMO at 0.5 m/s at a person who walks head-on at 1.2 m/s until 5 cm from its body
    and then stands; ``step(k, s, map_or_None, x_person, v_person)`` returns the command's v, ω."""
    core = SafetyFilter(FilterConfig(), warm_up=False)
    model, dt = core.model, core.config.dt
    s, x_p, walking = FilterState.planar(0.0, 0.0, 0.0), 3.2, True
    vs, gaps = [], []
    for k in range(STEPS):
        v_p = -SPEED if walking else 0.0
        u = step(k, s, esdf(x_p) if k % 5 == 0 else None, x_p, v_p)
        vs.append(u[0])
        s = model.integrate(s, np.asarray(u), dt)
        x_p += v_p * dt
        body = model.points(s)[1:]
        gap = float((np.hypot(body[:, 0] - x_p, body[:, 1]) - PERSON - model.radius[1:]).min())
        gaps.append(gap)
        walking = walking and gap > 0.05
    k = int(np.argmin(gaps))
    return {"v": np.array(vs), "gap": np.array(gaps), "v_closest": vs[k],
            "first_brake": next((i for i, v in enumerate(vs) if v < 0.45), STEPS)}


def test_object_motion_is_a_setting_of_the_node():
    assert FilterSettings().object_motion is True
    assert FilterSettings(object_motion=False).filter_config().object_motion is False
    with pytest.raises(ValueError, match="object_motoin"):
        FilterSettings(object_motoin=False)  # type: ignore[call-arg]


def test_a_person_walking_at_the_robot_makes_the_node_stop_it_earlier(router_endpoint):
    robot = "t_sf_motion"
    args = ["--robot", robot, "--set", "map_timeout_s=60", "--set", "state_timeout_s=60", "--set", "ref_timeout_s=60",
            "--set", "map_margin_voxels=0", "--set", "status_period_s=0.2",
            # Each step's reference is its own cmd/ref source (its name marks the step's command),
            # ranked above every earlier step's, so the arbitration takes it at once. (Sources of
            # equal rank that expire after 1 ms raced: a step's reference could arrive within the
            # millisecond, be preempted by the previous step's, and the node keep that one.)
            "--set", "ref_sources=" + json.dumps({f"t{k}": {"priority": k + 1} for k in range(STEPS)})]
    root = f"rf/{robot}"
    with ServiceProcess("safety-filter", router_endpoint, args) as proc, client_session(router_endpoint) as session:
        assert wait_alive(session, f"{root}/alive/safety-filter"), proc.output
        cmds = Collector(session, f"{root}/cmd/safe", VelocityCommand)
        status = Collector(session, f"{root}/safety/status", SafetyStatus)
        node_status = Collector(session, f"{root}/status/safety-filter", NodeStatus)
        seq = [0]

        def over_zenoh(k, s, grid, x_p, v_p):
            if grid is not None:
                seq[0] += 1
                header = Header(stamp_ns=time.time_ns(), frame_id="map", seq=seq[0])
                objs = TrackedObjects(header=header, objects=[TrackedObject(
                    id=7, label=12, risk_group=1, position=(x_p, 0.0, 0.0), velocity=(v_p, 0.0, 0.0), radius=PERSON,
                    age_ms=0.0, tracked_ms=5000.0)])
                msg = to_grid_message(grid)
                msg.header = header
                put(session, f"{root}/map/objects", objs)
                put(session, f"{root}/map/esdf", msg)
            put(session, f"{root}/state", state_msg(s))
            ref = VelocityCommand(linear=(0.5, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source=f"t{k}")
            put(session, f"{root}/cmd/ref", ref)
            want = f"safety-filter/t{k}"
            assert wait_until(lambda: any(c.source == want for c in cmds.items[-8:]), 15.0), (
                k, [c.source for c in cmds.items[-8:]], proc.output)
            c = next(c for c in cmds.items[-8:] if c.source == want)  # the step on this reference (and state)
            return c.linear[0], c.angular[2]

        moving = scenario(over_zenoh)
        # The person's own row ran in the node's step.
        assert max(st.object_rows for st in status.items) >= 1
        assert wait_until(lambda: node_status.items and node_status.items[-1].extra.get("steps", 0) > 50, 10.0)
        cmds.close()
        status.close()
        node_status.close()
    static_core = SafetyFilter(FilterConfig(map_margin_voxels=0))
    fields: list = [None]

    def in_process(k, s, grid, x_p, v_p):
        fields[0] = grid if grid is not None else fields[0]
        res = static_core.filter(s, np.array([0.5, 0.0]), fields[0])
        return res.u[0], res.u[1]

    static = scenario(in_process)
    assert moving["first_brake"] < static["first_brake"], (moving["first_brake"], static["first_brake"])
    assert moving["v_closest"] <= 0.01, moving["v_closest"]  # stopped at the closest approach
    assert moving["v"].min() >= -1e-6  # and never backed away on its own: it yields, the person walked up
