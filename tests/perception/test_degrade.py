"""Statistics of the degradation model: depth noise σ(z) = a + b·z², confidence from range and
incidence, label noise where labels change, wrong labels, pose drift, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from oracles.sim_perception import cos_incidence, normals_from_pointmap
from riskfield.services.perception import kernels
from riskfield.services.perception.degrade import DegradationConfig, Degrader, boundary_mask


def plane(depth: float, h: int = 120, w: int = 160, f: float = 100.0, tilt: float = 0.0) -> np.ndarray:
    """Pointmap of a plane z = depth + tilt·x seen by a pinhole camera."""
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    rx, ry = (uu - (w - 1) / 2) / f, (vv - (h - 1) / 2) / f
    z = depth / (1 - tilt * rx)
    return np.stack([rx * z, ry * z, z], -1).astype(np.float32)


@pytest.mark.parametrize("depth", [1.0, 3.0, 6.0])
def test_depth_noise_grows_quadratically_with_range(depth):
    cfg = DegradationConfig(noise_a=0.01, noise_b=0.005, p_boundary=0, p_confuse=0, p_salt=0)
    pts = plane(depth, f=5000.0)  # narrow field of view: every ray meets the plane head-on
    hw = pts.shape[:2]
    obs = Degrader(cfg, seed=1).observe(pts, np.zeros(hw, np.uint16), np.eye(4), np.ones(hw, bool))
    err = (obs.points[..., 2] - pts[..., 2])[2:-2, 2:-2]  # head-on plane: no incidence inflation
    assert err.std() == pytest.approx(cfg.sigma(depth), rel=0.05)
    assert abs(err.mean()) < 3 * cfg.sigma(depth) / np.sqrt(err.size) + 1e-6  # unbiased
    # Noise moves points along their rays: the pixel does not change.
    np.testing.assert_allclose(obs.points[..., 0] / obs.points[..., 2], pts[..., 0] / pts[..., 2], atol=1e-5)


def test_confidence_falls_with_range_and_incidence():
    cfg = DegradationConfig()
    ones = np.ones((120, 160), bool)
    near = Degrader(cfg).observe(plane(1.0), np.zeros((120, 160), np.uint16), np.eye(4), ones).confidence
    far = Degrader(cfg).observe(plane(6.0), np.zeros((120, 160), np.uint16), np.eye(4), ones).confidence
    oblique = Degrader(cfg).observe(plane(1.0, tilt=1.5), np.zeros((120, 160), np.uint16), np.eye(4), ones).confidence
    assert np.median(near) > np.median(far) > 1.0
    assert np.median(near) > np.median(oblique)
    expect = 1 + cfg.c_gain * np.exp(-1.0 / cfg.z_scale)  # head-on at 1 m, centre pixel
    assert near[60, 80] == pytest.approx(expect, rel=1e-3)
    invalid = ones.copy()
    invalid[:10] = False
    c = Degrader(cfg).observe(plane(1.0), np.zeros((120, 160), np.uint16), np.eye(4), invalid).confidence
    assert np.all(c[:10] == 0) and np.all(c[10:] >= 1)


def test_normals_of_a_plane():
    pts = plane(2.0, tilt=1.0)
    n, ok = normals_from_pointmap(pts, np.ones(pts.shape[:2], bool))
    assert ok.all()
    expect = np.array([-1.0, 0.0, 1.0]) / np.sqrt(2)  # z − x = 2: normal ∝ (−1, 0, 1), flipped to face the camera
    np.testing.assert_allclose(n[60, 80], -expect, atol=1e-3)
    c = cos_incidence(pts, n, ok)
    assert c[60, 80] == pytest.approx(abs(np.dot(-expect, pts[60, 80] / np.linalg.norm(pts[60, 80]))), abs=1e-3)
    compiled = np.empty(pts.shape[:2], np.float32)
    kernels.incidence_kernel(pts, np.ones(pts.shape[:2], bool), compiled)
    np.testing.assert_array_equal(compiled, c)  # the kernel the degrader runs


def test_boundary_mask_width():
    labels = np.zeros((20, 20), np.uint16)
    labels[:, 10:] = 5
    for width in (1, 2, 3):
        m = boundary_mask(labels, width)
        cols = np.nonzero(m.any(axis=0))[0]
        assert cols.min() == 10 - width and cols.max() == 9 + width
    assert not boundary_mask(labels, 0).any()


def test_label_noise_only_at_boundaries_and_at_the_configured_rate():
    labels = np.zeros((200, 200), np.uint16)
    labels[:, 100:] = 12
    cfg = DegradationConfig(boundary_px=2, p_boundary=0.3, p_confuse=0, p_salt=0)
    out = Degrader(cfg, seed=2).degrade_labels(labels)
    changed = out != labels
    assert not changed[:, :98].any() and not changed[:, 102:].any()  # only within 2 px of the edge
    band = boundary_mask(labels, 2)
    # A picked pixel takes a random neighbour's label: it differs from its own in about half the cases.
    assert 0.08 < changed[band].mean() < 0.22
    assert set(np.unique(out)) == {0, 12}


def test_wrong_labels_happen_occasionally_and_plausibly():
    labels = np.zeros((100, 100), np.uint16)
    labels[30:70, 30:70] = 126  # an animal
    cfg = DegradationConfig(p_boundary=0, p_confuse=0.2, p_salt=0)
    d = Degrader(cfg, seed=3)
    frames = [d.degrade_labels(labels) for _ in range(300)]
    hit = [f for f in frames if (f != labels).any()]
    assert 0.12 < len(hit) / 300 < 0.28
    wrong = {int(v) for f in hit for v in np.unique(f[f != labels])}
    assert wrong <= {39, 108, 12}  # cushion, plaything, person
    assert all((f[labels == 0] == 0).all() for f in frames)  # structure never relabelled wholesale


def test_salt_noise_rate():
    labels = np.zeros((300, 300), np.uint16)
    out = Degrader(DegradationConfig(p_boundary=0, p_confuse=0, p_salt=0.01), seed=4).degrade_labels(labels)
    assert (out != 0).mean() == pytest.approx(0.01 * 149 / 150, rel=0.15)


def test_pose_drift_is_a_random_walk():
    cfg = DegradationConfig(drift_t=0.01, drift_yaw=0.0)
    finals = []
    for seed in range(40):
        d = Degrader(cfg, seed=seed)
        for _ in range(100):
            T = d._drifted(np.eye(4))
        finals.append(T[0, 3])
    assert np.std(finals) == pytest.approx(0.01 * np.sqrt(100), rel=0.3)
    assert np.array_equal(Degrader(DegradationConfig(), 0)._drifted(np.eye(4)), np.eye(4))  # off by default


def test_deterministic_for_a_seed_and_perfect_config_is_identity():
    pts = plane(2.0)
    labels = np.zeros(pts.shape[:2], np.uint16)
    labels[:, 80:] = 7
    ones = np.ones(pts.shape[:2], bool)
    a = Degrader(seed=5).observe(pts, labels, np.eye(4), ones)
    b = Degrader(seed=5).observe(pts, labels, np.eye(4), ones)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.labels, b.labels)
    p = Degrader(DegradationConfig.perfect()).observe(pts, labels, np.eye(4), ones)
    np.testing.assert_allclose(p.points, pts, atol=1e-6)
    np.testing.assert_array_equal(p.labels, labels)
    with pytest.raises(ValueError):
        DegradationConfig(p_salt=2.0)
    with pytest.raises(ValueError):
        DegradationConfig(noise_a=float("nan"))
