"""The Rerun viewer draws the tracked people and animals (``map/objects``): their extent tinted by risk
group, labelled, and their velocities as arrows; read back from view.rrd with the rerun SDK."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from riskfield.protocol import Header, TrackedObject, TrackedObjects, ade20k
from riskfield.services.viewer.draw import GROUP_TINT, tracked_objects


def people() -> TrackedObjects:
    return TrackedObjects(header=Header(stamp_ns=7), objects=[
        TrackedObject(id=3, label=ade20k.index("person"), risk_group=1, position=(1.0, -0.5, 0.8),
                      velocity=(0.0, 1.2, 0.0), radius=0.25, age_ms=0.0),
        TrackedObject(id=9, label=ade20k.index("ball"), risk_group=3, position=(2.0, 0.5, 0.1),
                      velocity=(0.3, 0.0, 0.0), radius=0.1, age_ms=0.0)])


def test_tracked_objects_as_points_arrows_and_labels():
    pos, radii, vel, tint, labels = tracked_objects(people())
    np.testing.assert_allclose(pos, [[1.0, -0.5, 0.8], [2.0, 0.5, 0.1]])
    np.testing.assert_allclose(radii, [0.25, 0.1]) and np.testing.assert_allclose(vel[0], [0, 1.2, 0])
    assert tint.tolist() == [list(GROUP_TINT["high"]), list(GROUP_TINT["low"])]
    assert labels == ["person #3 1.20 m/s", "ball #9 0.30 m/s"]
    empty = tracked_objects(TrackedObjects())
    assert empty[0].shape == (0, 3) and empty[2].shape == (0, 3) and empty[4] == []


def test_viewer_node_draws_tracked_objects(router_endpoint, tmp_path):
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from riskfield.services.runtime import Node
    from riskfield.services.viewer.node import ViewerSettings, setup
    from riskfield.testing import client_session, put, wait_until

    s = ViewerSettings(connect=[router_endpoint], robot="t_view_obj", out=tmp_path)
    node = Node("viewer", s)
    view = setup(node, s)
    t = threading.Thread(target=node.run, daemon=True)
    t.start()
    try:
        with client_session(router_endpoint) as c:
            # repeated until drawn: the first put may reach the router before the subscription does
            assert wait_until(lambda: (put(c, "rf/t_view_obj/map/objects", people()),
                                       view.drawn["objects"] >= 1)[1], 10, period_s=0.1)
    finally:
        node.stop()
        t.join(10)
        view.close()
    by_entity: dict[str, list] = {}
    for chunk in RrdReader(tmp_path / "view.rrd").stream():
        by_entity.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())

    def column(path: str, name: str) -> list:
        return [row for b in by_entity[path] if name in b.schema.names
                for row in b.column(b.schema.names.index(name)).to_pylist()]

    np.testing.assert_allclose(column("/world/objects", "Points3D:positions")[-1], [[1.0, -0.5, 0.8], [2.0, 0.5, 0.1]])
    np.testing.assert_allclose(column("/world/objects", "Points3D:radii")[-1], [0.25, 0.1])
    assert column("/world/objects", "Points3D:labels")[-1] == ["person #3 1.20 m/s", "ball #9 0.30 m/s"]
    np.testing.assert_allclose(column("/world/objects/velocity", "Arrows3D:vectors")[-1], [[0, 1.2, 0], [0.3, 0, 0]])
    np.testing.assert_allclose(column("/world/objects/velocity", "Arrows3D:origins")[-1], [[1.0, -0.5, 0.8],
                                                                                          [2.0, 0.5, 0.1]])
