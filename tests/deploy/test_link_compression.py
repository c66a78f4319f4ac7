"""The routers' link is compressed: two routers built as riskfield's router builds its session
(``RouterSettings`` → ``zenoh_config``), joined by the loopback relay of
``riskfield.experiments.shaped_link`` (unshaped: it only counts the bytes) as ``riskfield bench link``
joins them, carry a map/esdf stream in a fraction of its bytes; with one end's compression off, Zenoh
does not compress at all (both ends must enable it), and the wire carries at least the payload."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import zenoh
from scipy import ndimage

from riskfield.experiments.benches.link import robot_site
from riskfield.protocol import EsdfGrid, Header, encode
from riskfield.services.runtime.processes import router_settings
from riskfield.services.runtime.router import RouterSettings
from riskfield.services.runtime.session import zenoh_config
from riskfield.testing import free_port, wait_matched

ROOT = "rf/t_lz"
KEY = f"{ROOT}/map/esdf"
N = 12


def room_esdf(seq: int) -> EsdfGrid:
    """The default map's 2-D slice (121 × 121, 0.05 m) of a room: walls, a sofa and a person, the signed
    distance clipped at 2 m, the risk groups, and the floor seen free around the robot."""
    n, voxel = 121, 0.05
    occ = np.zeros((n, n), bool)
    occ[:4], occ[-4:], occ[:, :4] = True, True, True
    occ[70:90, 20:60] = True  # a sofa
    occ[40 + seq % 5:46 + seq % 5, 80:86] = True  # a person walking
    groups = np.where(occ, 2, 0).astype(np.uint8)
    groups[40:51, 80:86] = np.where(occ[40:51, 80:86], 1, 0)
    d = (ndimage.distance_transform_edt(~occ) - ndimage.distance_transform_edt(occ)) * voxel
    dist = np.clip(d, -2.0, 2.0).astype(np.float32)[:, :, None]
    yy, xx = np.mgrid[:n, :n]
    free = (np.hypot(xx - 60, yy - 60) < 40) & ~occ
    return EsdfGrid(header=Header(stamp_ns=10**18 + seq, frame_id="map"), origin=(-3.0, -3.0, 0.35),
                    voxel_size=voxel, distance=dist, risk_group=groups[:, :, None],
                    groups=["high", "mid", "low"], max_distance=2.0, unknown_is_occupied=False,
                    observed_free=free[:, :, None])


def carried(robot_compression: bool) -> tuple[int, int]:
    """(payload bytes, bytes the relay carried from the server's router to the robot's) for N maps,
    the robot's site as ``riskfield bench link`` builds it."""
    server_port = free_port()
    server = zenoh.open(zenoh_config(router_settings(f"tcp/127.0.0.1:{server_port}")))
    try:
        got = threading.Semaphore(0)
        with robot_site(server_port, ROOT, robot_compression, lambda _s: got.release()) as link:
            assert wait_matched(server, KEY, 30)
            payloads = [encode(room_esdf(i)) for i in range(N)]
            # Blocking, not map/esdf's drop: a burst of maps on a busy machine would drop some.
            pub = server.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
            before = link.down.bytes
            for p in payloads:
                pub.put(p)
            assert all(got.acquire(timeout=10) for _ in payloads)
            pub.undeclare()
            return sum(map(len, payloads)), link.down.bytes - before
    finally:
        server.close()


def test_riskfields_router_compresses_its_links_unless_told_not_to() -> None:
    assert RouterSettings().zenoh_extra() == {"transport/unicast/compression/enabled": True}
    cfg = zenoh_config(RouterSettings(compression=False))
    assert cfg.get_json("transport/unicast/compression/enabled") == "false"


@pytest.mark.xdist_group("routers")
def test_the_link_between_two_routers_carries_maps_compressed_and_not_when_one_end_declines() -> None:
    payload, wire = carried(robot_compression=True)
    assert wire < 0.4 * payload, (payload, wire)
    payload_off, wire_off = carried(robot_compression=False)
    assert wire_off >= payload_off, (payload_off, wire_off)
