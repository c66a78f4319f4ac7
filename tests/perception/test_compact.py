"""The compact perception frame (``services/perception/compact.py``): depth + intrinsics at the
mapping's pixel stride instead of three float32 per pixel; what it loses, bounded; the mapper
takes it and full pointmaps alike."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import PerceptionFrame, RiskConfig, ade20k, decode, encode
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.mapper import Mapper
from riskfield.services.perception.compact import compact, frame_stride

F16_HALF_ULP = 2.0**-11  # float16 rounds to nearest: relative error ≤ half its 10-bit ulp


def _frame(cam: PinholeCamera, z: np.ndarray, offset_px: np.ndarray | None = None) -> PerceptionFrame:
    """A full frame: points on the pixel rays at depths ``z`` (optionally ``offset_px`` off them)."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    if offset_px is not None:
        u, v = u + offset_px[..., 0], v + offset_px[..., 1]
    pts = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], -1).astype(np.float32)
    labels = np.zeros(z.shape, np.uint16)
    labels[:, : cam.width // 2] = ade20k.index("person")
    return PerceptionFrame(T_WC=np.eye(4), points=pts, confidence=np.full(z.shape, 5.0, np.float32), labels=labels,
                           keyframe_id=3, intrinsics=cam.intrinsics)


cameras = st.builds(lambda w, h, f, dx, dy: PinholeCamera(w, h, f, f * 1.01, (w - 1) / 2 + dx, (h - 1) / 2 + dy),
                    st.integers(4, 40), st.integers(4, 30), st.floats(20.0, 600.0), st.floats(-3, 3), st.floats(-3, 3))


@settings(max_examples=60, deadline=None)
@given(cam=cameras, seed=st.integers(0, 2**31), stride=st.integers(1, 4))
def test_float16_depth_rebuilds_the_points_within_its_rounding(cam, seed, stride):
    """Over the wire and back: each point moves along its own ray by at most float16's rounding of z
    (≤ 0.98 mm at 4 m); the strided grid's intrinsics put pixel (u', v') on pixel (s·u', s·v')."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(1.0, 4.0, (cam.height, cam.width))
    full = _frame(cam, z)
    back = decode(encode(compact(full, "float16", stride)), PerceptionFrame)
    assert back.points is None and back.depth.dtype == np.float16
    want = full.points[::stride, ::stride]
    assert back.pixels == want.shape[:2] == (cam.strided(stride).height, cam.strided(stride).width)
    got = back.pointmap()
    err = np.linalg.norm(got - want, axis=-1)
    ray = np.linalg.norm(want, axis=-1) / want[..., 2]
    assert (err <= (F16_HALF_ULP * want[..., 2] + 2e-6) * ray).all()
    assert err.max() <= 1e-3 * ray.max()  # ≤ 1 mm along the ray below 4 m
    np.testing.assert_array_equal(back.labels, full.labels[::stride, ::stride])
    np.testing.assert_array_equal(back.confidence, full.confidence[::stride, ::stride])


@settings(max_examples=40, deadline=None)
@given(cam=cameras, seed=st.integers(0, 2**31))
def test_a_point_off_its_ray_comes_back_on_it_at_the_same_depth(cam, seed):
    """A fused keyframe point sits up to half a pixel off the current pixel's ray: depth + intrinsics
    put it back on the ray, ≤ half a pixel's footprint √2·z/(2f) plus the rounding."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(1.0, 4.0, (cam.height, cam.width))
    off = rng.uniform(-0.5, 0.5, (cam.height, cam.width, 2))
    full = _frame(cam, z, off)
    got = decode(encode(compact(full, "float16")), PerceptionFrame).pointmap()
    err = np.linalg.norm(got - full.points, axis=-1)
    bound = np.hypot(0.5 / cam.fx, 0.5 / cam.fy) * z + 2 * F16_HALF_ULP * z * np.linalg.norm(full.points, axis=-1) / z
    assert (err <= bound + 1e-5).all()


def test_the_compact_frame_is_a_ninth_of_the_full_size_one():
    """The default 512×384 camera: the full frame 3.54 MB; depth float16 at stride 2 under 0.4 MB."""
    cam = PinholeCamera()
    full = _frame(cam, np.full((cam.height, cam.width), 2.0))
    full_size = len(encode(full))
    small = len(encode(compact(full, "float16", 2)))
    assert full_size > 3.5e6 and small < 0.4e6, (full_size, small)
    assert len(encode(compact(full, "float32", 2))) < 0.5e6


def test_what_the_contract_refuses():
    cam = PinholeCamera(8, 6, 5.0, 5.0, 3.5, 2.5)
    f = compact(_frame(cam, np.full((6, 8), 2.0)))
    m = {k: getattr(f, k) for k in ("T_WC", "confidence", "labels", "keyframe_id", "depth", "intrinsics")}
    with pytest.raises(ValueError, match="intrinsics"):
        PerceptionFrame(**{**m, "intrinsics": None})
    with pytest.raises(ValueError, match="not both"):
        PerceptionFrame(**m, points=np.zeros((6, 8, 3), np.float32))
    with pytest.raises(ValueError, match="points or depth"):
        PerceptionFrame(**{**m, "depth": None})
    with pytest.raises(ValueError, match="≥ 0"):
        PerceptionFrame(**{**m, "depth": -np.ones((6, 8), np.float16)})
    with pytest.raises(ValueError, match="differs"):
        PerceptionFrame(**{**m, "depth": np.ones((5, 8), np.float16)})
    with pytest.raises(ValueError):  # float64 on the wire is not float16 or float32
        decode(encode(f).replace(b"<f2", b"<f8"), PerceptionFrame)
    # no intrinsics (a network's pointmap, not a pinhole's): sent as it is
    bare = _frame(cam, np.full((6, 8), 2.0)).model_copy(update={"intrinsics": None})
    assert compact(bare) is bare


def test_frame_stride():
    assert frame_stride((384, 512), (384, 512)) == 1
    assert frame_stride((384, 512), (192, 256)) == 2
    assert frame_stride((95, 127), (48, 64)) == 2
    assert frame_stride((384, 512), (100, 256)) is None


def test_the_mapper_maps_a_compact_frame_as_the_full_one():
    """A full pointmap and its compact form (float16, stride 2) give the same occupancy: people
    1.5 m ahead beside a wall at 2.1 m (the pixels between the stride's left out)."""
    cam = PinholeCamera(64, 48, 40.0, 40.0, 31.5, 23.5)
    z = np.full((48, 64), 1.5)
    z[:, 40:] = 2.1
    T = np.eye(4)
    T[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]  # looking along +x
    full = _frame(cam, z).model_copy(update={"T_WC": T})
    full.header.stamp_ns = 10**9
    small = decode(encode(compact(full, "float16", 2)), PerceptionFrame)
    grids = []
    for f in (full, small):
        m = Mapper(MapperConfig(half_extent=(2.5, 2.0, 1.0), recentre_distance=100.0, output="3d"), RiskConfig())
        m.set_robot_position(np.zeros(3))
        for _ in range(3):
            assert m.integrate_frame(f).rays > 0
        grids.append(m.occupancy())
    a, b = grids
    for group in (1, 3):  # the person (high) and the wall behind (low), solid interiors included
        A, B = a == group, b == group
        assert A.sum() > 1000 and (A & B).sum() / (A | B).sum() > 0.95, (group, A.sum(), B.sum(), (A & B).sum())
