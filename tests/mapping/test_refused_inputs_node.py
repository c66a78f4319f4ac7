"""The mapping node refuses what would move its volume or its clock wrongly, over a real Zenoh
router with the node in its own process: a state that jumps farther than the robot can move
(unless announced on ``state/relocalise``) and a frame stamped in the future. Both are counted
and change nothing: the next ESDF has the volume where it was and no stamp from the future."""

from __future__ import annotations

import time

import numpy as np
import pytest
import zenoh

from riskfield.protocol import (
    ENCODING,
    DistanceQuery,
    EsdfGrid,
    Header,
    Keys,
    PerceptionFrame,
    RobotState,
    ade20k,
    encode,
)
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Plane, render
from riskfield.services.geometry.transforms import orbit
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.mapper import Mapper
from riskfield.testing import Collector, ServiceProcess, StatusWatch, client_session, put, wait_alive, wait_until

CAM = PinholeCamera.centred(160, 120, 125.0)
S = 1_000_000_000


def room() -> list:
    return [Plane((1, 0, 0), 1.5, ade20k.index("wall")), Plane((0, 0, 1), 0.0, ade20k.index("floor")),
            Box((0.8, -0.7, 0.0), (1.0, -0.4, 1.2), ade20k.index("person"))]


def frame(i: int = 0, stamp_ns: int | None = None) -> PerceptionFrame:
    T = orbit([1.2, 0.0, 0.3], n=4, radius=0.2, height=0.3)[i % 4]
    pts, conf, lab = render(room(), T, CAM)
    header = Header(stamp_ns=time.time_ns() if stamp_ns is None else stamp_ns)
    return PerceptionFrame(header=header, T_WC=T, points=pts, confidence=conf, labels=lab, keyframe_id=i)


def robot_state(x: float) -> RobotState:
    return RobotState(position=(x, 0.0, 0.0), orientation=(0, 0, 0, 1), linear_velocity=(0, 0, 0),
                      angular_velocity=(0, 0, 0))


def ready(session: zenoh.Session, keys: Keys, timeout_s: float = 60.0) -> bool:
    """Liveliness comes up before the node has warmed its kernels and declared its queryable."""
    payload = encode(DistanceQuery(points=np.zeros((1, 3))))

    def answers() -> bool:
        replies = session.get(keys.esdf_query, payload=payload, encoding=zenoh.Encoding(ENCODING), timeout=0.5)
        return any(r.ok is not None for r in replies)

    return wait_until(answers, timeout_s, 0.1)


def test_a_state_jump_and_a_future_frame_are_refused_and_move_nothing(router_endpoint: str) -> None:
    keys = Keys("t_map_refuse")
    args = ["--robot", keys.robot, "--set", "esdf_rate_hz=20", "--set", "status_period_s=0.05"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")) and ready(s, keys), proc.output
        grids = Collector(s, keys.esdf, EsdfGrid)
        status = StatusWatch(s, keys.status("mapping"))
        put(s, keys.state, robot_state(0.0))
        status.wait(lambda st: st.received.get("state", 0) >= 1)
        put(s, keys.perception_frame, frame(0))
        origin = np.asarray(grids.wait(1)[-1].origin)
        # 100 m away 50 ms later: before, the volume recentred past every voxel and the map was gone.
        put(s, keys.state, robot_state(100.0))
        status.wait(lambda st: st.extra.get("state_refused_state_jump", 0) >= 1)
        n = len(grids.items)
        put(s, keys.perception_frame, frame(1))
        g = grids.wait(n + 1)[-1]
        assert np.allclose(g.origin, origin) and (g.distance < 0).any()
        assert all(np.allclose(x.origin, origin) for x in grids.items)
        # A frame stamped 1 h ahead: refused, so no ESDF carries a stamp from the future; the next
        # frame's ESDF (its stamp) shows the node handled both.
        put(s, keys.perception_frame, frame(2, stamp_ns=time.time_ns() + 3600 * S))
        status.wait(lambda st: st.extra.get("future_frames", 0) >= 1)
        late = frame(3)
        put(s, keys.perception_frame, late)
        assert wait_until(lambda: grids.items[-1].header.stamp_ns == late.header.stamp_ns, 10), proc.output
        assert max(x.header.stamp_ns for x in grids.items) <= time.time_ns()
        # Announced, the jump is taken: the volume follows the robot.
        put(s, keys.key("state/relocalise"), robot_state(100.0))
        assert wait_until(lambda: grids.items[-1].origin[0] > origin[0] + 90, 10), proc.output
        assert "refused a state" in proc.output and "refused" in proc.output
        grids.close()
        status.close()
        assert proc.stop() == 0, proc.output


def test_the_mappers_clock_does_not_advance_on_a_refused_future_frame() -> None:
    from riskfield.services.mapping.mapper import FutureFrame

    m = Mapper(MapperConfig())
    now = time.time_ns()
    m.integrate_frame(frame(0, stamp_ns=now), latest_ns=now + S // 10)
    clock, stamp = m.now_ms, m.stamp_ns
    with pytest.raises(FutureFrame, match="after this clock allows"):
        m.integrate_frame(frame(1, stamp_ns=now + 3600 * S), latest_ns=now + S // 10)
    assert (m.now_ms, m.stamp_ns, m.frames) == (clock, stamp, 1)
