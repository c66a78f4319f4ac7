"""TSDF integration of rendered pointmaps by rays: the fused surface is where the true one is, for the
merged rays (the mapper's path for frames without intrinsics) and for one ray per pixel (their oracle,
``oracles.tsdf.RayTsdf``), and the two agree."""

from __future__ import annotations

import numpy as np
import pytest

from oracles.tsdf import RayTsdf
from riskfield.services.geometry.camera import PinholeCamera
from riskfield.services.geometry.shapes import Box, Plane, render
from riskfield.services.geometry.transforms import look_at, orbit
from riskfield.services.mapping.config import MapperConfig
from riskfield.services.mapping.layers import TsdfLayer
from riskfield.services.mapping.occupancy import surface_support
from riskfield.services.mapping.tsdf_integrator import TsdfIntegrator
from riskfield.services.mapping.volume import Volume

CAM = PinholeCamera.centred(160, 120, 125.0)


INTEGRATORS = {"merged": TsdfIntegrator, "ray": RayTsdf}


@pytest.fixture(params=list(INTEGRATORS))
def integration(request: pytest.FixtureRequest) -> str:
    """Both integrators: merged rays (production) and one ray per pixel (the oracle)."""
    return request.param


def fuse(scene: list, poses: list[np.ndarray], cfg: MapperConfig, integration: str,
         offset: float = 0.0) -> tuple[Volume, TsdfLayer]:
    vol = Volume.centred(cfg.voxel_size, cfg.shape, np.array([offset, 0.0, 0.0]))
    layer = TsdfLayer(vol.shape, cfg.truncation)
    integ = INTEGRATORS[integration](cfg)
    for T in poses:
        pts, conf, _ = render(scene, T, CAM)
        integ.integrate(vol, layer, pts, conf, T)
    return vol, layer


@pytest.mark.parametrize("x0", [1.0, 1.013, 1.037])
def test_plane_zero_crossing_within_a_voxel(x0: float, integration: str) -> None:
    """A wall at x = x0 (off the lattice too): the TSDF's zero crossing along x is within a voxel of it."""
    cfg = MapperConfig(half_extent=(1.5, 1.0, 1.0), pixel_stride=1)
    scene = [Plane((1, 0, 0), x0, 0)]
    vol, layer = fuse(scene, orbit([x0, 0, 0.0], n=3, radius=0.2, height=0.0), cfg, integration)
    c = vol.centres()
    checked = lines = 0
    for j in range(vol.shape[1]):
        for k in range(vol.shape[2]):
            w, d = layer.weight[:, j, k], layer.tsdf[:, j, k]
            seen = np.flatnonzero(w > 0)
            if seen.size < 4 or d[seen].min() > 0:
                continue  # this line never reaches the surface band (grazing or carving rays only)
            lines += 1
            signs = np.flatnonzero((d[seen][:-1] > 0) & (d[seen][1:] <= 0) & (np.diff(seen) == 1))
            if signs.size == 0:
                continue  # at the edge of the view the voxel in front of the surface is never crossed
            i = seen[signs[0]]
            xa, xb, da, db = c[i, j, k, 0], c[i + 1, j, k, 0], d[i], d[i + 1]
            x_zero = xa + (xb - xa) * da / (da - db)
            assert abs(x_zero - x0) < cfg.voxel_size
            checked += 1
    assert checked > 0.9 * lines and checked > 100
    # and every voxel supporting the surface is within a voxel of the plane
    occ = surface_support(layer, cfg.min_weight, cfg.surface_band)
    assert occ.sum() > 100
    assert np.abs(c[occ][:, 0] - x0).max() < cfg.voxel_size


def test_box_surface_support_hugs_the_box(integration: str) -> None:
    """Every supported voxel is within a voxel of the box, and the visible faces are covered."""
    cfg = MapperConfig(half_extent=(1.5, 1.5, 1.0), pixel_stride=1, min_weight=0.5)
    box = Box((0.6, -0.2, -0.25), (0.9, 0.25, 0.2), 0)
    poses = [look_at(np.array([0.0, y, 0.05]), np.array([0.75, 0.0, 0.0])) for y in (-0.3, 0.0, 0.3)]
    vol, layer = fuse([box], poses, cfg, integration)
    occ = surface_support(layer, cfg.min_weight, cfg.surface_band)
    c = vol.centres()
    d = box.distance(c[occ])
    assert occ.sum() > 50
    assert np.abs(d).max() < cfg.voxel_size
    # the front face x = 0.6 is fully covered: each lattice (y, z) on it has a supported voxel near it
    ys = np.arange(-0.15, 0.2 + 1e-9, cfg.voxel_size)
    zs = np.arange(-0.2, 0.15 + 1e-9, cfg.voxel_size)
    pts = c[occ]
    for y in ys:
        for z in zs:
            near = np.linalg.norm(pts - np.array([0.6, y, z]), axis=1).min()
            assert near <= cfg.voxel_size + 1e-6


def test_confidence_weights_and_the_weight_cap(integration: str) -> None:
    cfg = MapperConfig(half_extent=(1.0, 0.5, 0.5), pixel_stride=1, max_weight=3.0, min_confidence=0.2, carve=False)
    scene = [Plane((1, 0, 0), 0.8, 0)]
    T = look_at(np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    vol = Volume.centred(cfg.voxel_size, cfg.shape, np.zeros(3))
    layer = TsdfLayer(vol.shape, cfg.truncation)
    integ = INTEGRATORS[integration](cfg)
    pts, _, _ = render(scene, T, CAM)
    low = np.full(pts.shape[:2], 0.1, np.float32)
    integ.integrate(vol, layer, pts, low, T)
    assert layer.weight.max() == 0, "pixels under min_confidence must be skipped"
    bad = pts.copy()
    bad[...] = 0.0  # zero range: invalid
    integ.integrate(vol, layer, bad, np.ones(pts.shape[:2], np.float32), T)
    assert layer.weight.max() == 0, "pixels with no range must be skipped"
    for _ in range(5):
        integ.integrate(vol, layer, pts, np.ones(pts.shape[:2], np.float32), T)
    assert layer.weight.max() == pytest.approx(3.0)
    assert np.abs(layer.tsdf).max() <= cfg.truncation + 1e-6


def test_merged_rays_agree_with_per_pixel_rays_on_the_surface() -> None:
    """The merged rays put the fused surface of a scene in (nearly all) the voxels one ray per pixel does."""
    scene = [Plane((1, 0, 0), 1.2, 0), Box((0.6, -0.3, -0.4), (0.8, 0.0, 0.3), 1)]
    poses = orbit([1.0, 0.0, 0.0], n=3, radius=0.2, height=0.0)
    supports = []
    cfg = MapperConfig(half_extent=(1.5, 1.0, 1.0), pixel_stride=1)
    for mode in ("merged", "ray"):
        vol, layer = fuse(scene, poses, cfg, mode)
        supports.append(vol.centres()[surface_support(layer, cfg.min_weight, cfg.surface_band)])
    merged, ray = supports
    assert len(merged) > 200 and abs(len(merged) - len(ray)) < 0.2 * len(ray)
    for a, b in ((merged, ray), (ray, merged)):
        nearest = np.sqrt(((a[:, None, :] - b[None]) ** 2).sum(-1)).min(1)
        assert np.mean(nearest == 0) > 0.9
        assert np.quantile(nearest, 0.9) <= 0.05 + 1e-6


def test_carving_clears_an_obstacle_that_moved_away(integration: str) -> None:
    cfg = MapperConfig(half_extent=(1.5, 1.0, 1.0), pixel_stride=1, max_weight=5.0)
    wall = Plane((1, 0, 0), 1.4, 0)
    person = Box((0.6, -0.2, -0.5), (0.8, 0.2, 0.5), 1)
    T = look_at(np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    vol = Volume.centred(cfg.voxel_size, cfg.shape, np.zeros(3))
    layer = TsdfLayer(vol.shape, cfg.truncation)
    integ = TsdfIntegrator(cfg) if integration == "merged" else RayTsdf(cfg, carve_stride=1)
    for _ in range(3):
        integ.integrate(vol, layer, *render([wall, person], T, CAM)[:2], T)
    i = tuple(vol.to_index(np.array([0.6, 0.0, 0.0])))
    assert surface_support(layer, cfg.min_weight, cfg.surface_band)[i]
    for _ in range(3):
        integ.integrate(vol, layer, *render([wall], T, CAM)[:2], T)
    assert not surface_support(layer, cfg.min_weight, cfg.surface_band)[i]
    assert layer.tsdf[i] > cfg.surface_band
