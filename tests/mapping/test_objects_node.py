"""The mapping node's ``map/objects`` over a real Zenoh router: a walking person's track and velocity,
stamped like the ESDF it was extracted from."""

from __future__ import annotations

import time

import numpy as np

from riskfield.protocol import EsdfGrid, Header, Keys, PerceptionFrame, RiskConfig, TrackedObjects, ade20k
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Plane, render
from riskfield.services.geometry.transforms import look_at
from riskfield.testing import Collector, ServiceProcess, client_session, put, wait_alive, wait_until

from .test_node import ready, state

CAM = PinholeCamera.centred(160, 120, 125.0)
PERSON, CHAIR = ade20k.index("person"), ade20k.index("chair")
HIGH = RiskConfig().group_id("high")


def walking(n: int, t0_ns: int) -> list[PerceptionFrame]:
    """A person (0.4 × 0.4 × 1.7 m) walking across the view at 1 m/s (+y), 1.3 m ahead, past a
    chair, filmed at 10 Hz from a standing camera; frames stamped 100 ms apart."""
    T = look_at(np.array([0.0, 0.0, 0.5]), np.array([2.0, 0.0, 0.4]))
    out = []
    for i in range(n):
        y = -0.6 + 0.1 * i
        scene = [Plane((1, 0, 0), 2.4, ade20k.index("wall")), Plane((0, 0, 1), 0.0, ade20k.index("floor")),
                 Box((1.0, 0.55, 0.0), (1.4, 0.85, 0.9), CHAIR), Box((1.1, y - 0.2, 0.0), (1.5, y + 0.2, 1.7), PERSON)]
        pts, conf, lab = render(scene, T, CAM)
        out.append(PerceptionFrame(header=Header(stamp_ns=t0_ns + i * 100_000_000), T_WC=T, points=pts,
                                   confidence=conf, labels=lab, keyframe_id=i,
                                   intrinsics=(CAM.fx, CAM.fy, CAM.cx, CAM.cy)))
    return out


def test_node_publishes_a_walking_persons_velocity_stamped_like_the_esdf(router_endpoint: str) -> None:
    keys = Keys("t_map_objects")
    args = ["--robot", keys.robot, "--set", "esdf_rate_hz=50"]
    with ServiceProcess("mapping", router_endpoint, args) as proc, client_session(router_endpoint) as s:
        assert wait_alive(s, keys.alive("mapping")) and ready(s, keys), proc.output
        grids = Collector(s, keys.esdf, EsdfGrid)
        objects = Collector(s, keys.objects, TrackedObjects)
        put(s, keys.state, state())
        # Stamped in the past, 100 ms apart up to about now: the mapper refuses frames from the future.
        sent = walking(9, time.time_ns() - 900_000_000)
        for f in sent:
            # The next frame goes once this one is in the map: its ESDF or its objects have arrived
            # (under load a publication can be dropped on the way: the runtime's publishers keep
            # zenoh-python's default, ``CongestionControl.DEFAULT = DROP`` in ``zenoh/__init__.pyi``).
            def arrived(stamp: int = f.header.stamp_ns) -> bool:
                return any(m.header.stamp_ns >= stamp for m in [*grids.items, *objects.items])

            put(s, keys.perception_frame, f)
            assert wait_until(arrived, 20.0), proc.output
        wait_until(lambda: len(objects.items) >= 9, 2.0)  # the last may still be on its way (or dropped)
        # One objects message per ESDF, with that ESDF's header stamp (the frame's): matched by the
        # publisher's sequence number, which both keys count up together.
        esdf_by_seq = {g.header.seq: g.header.stamp_ns for g in grids.items}
        frame_stamps = [f.header.stamp_ns for f in sent]
        matched = [o for o in objects.items if o.header.seq in esdf_by_seq]
        assert len(matched) >= 5
        assert all(o.header.stamp_ns == esdf_by_seq[o.header.seq] for o in matched)
        assert all(o.header.stamp_ns == frame_stamps[o.header.seq] for o in objects.items)
        people = [o for msg in objects.items for o in msg.objects]
        assert people and all(o.label == PERSON and o.risk_group == HIGH for o in people), "the chair is no object"
        assert len({o.id for o in people}) == 1, "one person, one track"
        seen = [o for o in people if o.age_ms == 0.0]
        # walking towards +y: never a velocity the other way, and once tracked, the right sign
        assert all(o.velocity[1] >= 0.0 for o in seen)
        moving = [o for o in seen if o.tracked_ms >= 200.0]
        assert moving and max(o.velocity[1] for o in moving) > 0.3, people
        assert all(np.hypot(*o.velocity[:2]) <= 3.0 for o in people)
        grids.close()
        objects.close()
        assert proc.stop() == 0
