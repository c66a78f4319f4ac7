"""The ESDF output stage on its own: an occupancy in, the published grids and the queried field out."""

from __future__ import annotations

import numpy as np
import pytest

from riskfield.protocol import Header
from riskfield.services.mapping.config import EsdfParams
from riskfield.services.mapping.esdf_integrator import EsdfIntegrator
from riskfield.services.mapping.esdf_output import EsdfOutput
from riskfield.services.mapping.volume import Volume

VOXEL = 0.1
GROUPS = ["high", "mid", "low"]
MARGINS = np.array([0.0, 0.2, 0.1, 0.0])  # per group id; 0 is free
SHAPE = (24, 20, 12)


def volume() -> Volume:
    return Volume.centred(VOXEL, SHAPE, np.array([0.0, 0.0, 0.5]))


def box(group: int = 2, x0: int = 14) -> np.ndarray:
    groups = np.zeros(SHAPE, np.uint8)
    groups[x0:x0 + 3, 8:12, :8] = group
    return groups


def output(kind: str) -> EsdfOutput:
    return EsdfOutput(EsdfParams(output=kind, band=(0.1, 0.6), max_distance=1.0), VOXEL, unknown_is_occupied=False)


def test_the_slice_covers_the_band_above_the_base_and_carries_the_floor_observed_free() -> None:
    out, vol = output("2d"), volume()
    k_lo, k_hi, z = out.band_indices(vol, base_z=0.0)
    centres = vol.origin[2] + VOXEL * np.arange(SHAPE[2])
    assert z == pytest.approx(0.35)
    assert list(np.flatnonzero((centres >= 0.1 - 1e-9) & (centres <= 0.6 + 1e-9))) == list(range(k_lo, k_hi))
    seen: list[np.ndarray] = []

    def free(band_obstacle: np.ndarray) -> np.ndarray:
        seen.append(band_obstacle)
        return (~band_obstacle[..., None]).astype(np.uint8)

    groups = box()
    up = out.build(groups, vol, Header(stamp_ns=7), MARGINS, GROUPS, 0.0, free)
    assert up.grid3d is None and up.slice2d is not None and up.primary is up.slice2d
    assert up.slice2d.origin[2] == pytest.approx(z) and up.slice2d.header.stamp_ns == 7
    np.testing.assert_array_equal(seen[0], (groups[:, :, k_lo:k_hi] > 0).any(axis=2))
    assert up.slice2d.observed_free is not None and not up.slice2d.observed_free[15, 9, 0]
    expected, _ = EsdfIntegrator(out.params, VOXEL).compute_slice(groups, k_lo, k_hi, MARGINS)
    np.testing.assert_array_equal(up.slice2d.distance, expected)
    assert up.occupancy is groups


def test_the_3d_grid_follows_edits_as_a_full_compute_would_and_the_field_is_the_primary_grid() -> None:
    out, vol = output("both"), volume()
    full = EsdfIntegrator(out.params, VOXEL)
    for groups in (box(), box(x0=12), box(group=1, x0=12)):  # moved, then its risk group changed
        up = out.build(groups, vol, Header(), MARGINS, GROUPS, 0.0, None)
        assert up.grid3d is not None and up.slice2d is not None and up.slice2d.observed_free is None
        d, g = full.compute(groups, MARGINS)
        np.testing.assert_allclose(up.grid3d.distance, d, atol=1e-5, rtol=0)
        np.testing.assert_array_equal(up.grid3d.risk_group, g)
    p = np.array([[0.0, 0.0, 0.35], [1.0, 0.5, 0.35]])
    np.testing.assert_allclose(out.query(p).distance, out.field.query(p).distance)  # type: ignore[union-attr]
    out.forget()
    up = out.build(box(), vol, Header(), MARGINS * 2, GROUPS, 0.0, None)
    np.testing.assert_allclose(up.grid3d.distance, full.compute(box(), MARGINS * 2)[0], atol=1e-5, rtol=0)


def test_before_any_grid_a_query_answers_unknown_space() -> None:
    out = output("2d")
    sample = out.query(np.zeros((3, 3)))
    assert sample.distance.shape == (3,) and not sample.inside.any()
