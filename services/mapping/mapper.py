"""The Mapper: the rolling volume, its layers and the integrators, composed (Algorithm 1).

    integrate(frame)   pointmap + pose + confidence → TSDF layer      (TsdfIntegrator)
                       labels + confidence          → semantic layer  (SemanticIntegrator, vote rule)
                       with the frame's intrinsics: both in one projective pass (ProjectiveIntegrator)
    update_esdf()      TSDF surface + solid interior + labels → semantic occupancy (occupancy.py)
                       → semantically inflated signed ESDF, 3-D and/or the 2-D slice (EsdfIntegrator;
                       the 3-D grid incrementally from the last one while volume and margins stay)
    query(points)      distance, gradient, risk group of the latest field (fields.EsdfField)

The volume follows the robot: ``set_robot_position`` (from ``RobotState``) recentres it
once the robot is ``recentre_distance`` from its centre, keeping the overlapping voxels.
Before any state arrives it follows the camera of the incoming frames instead, and the
2-D slice's height band is measured from z = 0.

The mapper has no I/O; it is driven by the mapping node, the benchmark and the tests.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from riskfield.protocol import EsdfGrid, Header, PerceptionFrame, RiskConfig

from ..fields import EsdfField, FieldSample, answer_query, unknown_sample
from .config import MapperConfig
from .esdf_integrator import EsdfIntegrator
from .keyframes import KeyframeMap
from .layers import SemanticLayer, TsdfLayer
from .occupancy import semantic_occupancy
from .pointmap import FrameRejected, check_pointmap, check_pose
from .projective_integrator import ProjectiveIntegrator
from .semantic_integrator import SemanticIntegrator
from .tsdf_integrator import TsdfIntegrator
from .volume import Volume


@dataclass
class FrameResult:
    rays: int
    votes: int
    shifted: bool
    ms: float


@dataclass
class MapUpdate:
    """The grids of one ESDF update: the 2-D slice and/or the 3-D grid, per ``output``."""

    slice2d: EsdfGrid | None = None
    grid3d: EsdfGrid | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)
    occupancy: np.ndarray | None = None
    """The semantic occupancy the grids were built from (per-voxel risk group; the tracker's input)."""

    @property
    def primary(self) -> EsdfGrid:
        """What goes on ``map/esdf``: the slice when one is built, else the 3-D grid."""
        grid = self.slice2d if self.slice2d is not None else self.grid3d
        assert grid is not None
        return grid


class Mapper:
    """Semantic TSDF → semantic occupancy → inflated signed ESDF, on a rolling local volume."""

    def __init__(self, config: MapperConfig | None = None, risk: RiskConfig | None = None):
        self.config = config or MapperConfig()
        c = self.config
        self.shape = c.shape
        self.volume: Volume | None = None
        self.tsdf = TsdfLayer(self.shape, c.truncation)
        self.semantic = SemanticLayer(self.shape)
        self.tsdf_integrator = TsdfIntegrator(c)
        self.semantic_integrator = SemanticIntegrator(c)
        self.projective_integrator = ProjectiveIntegrator(c)
        self.esdf_integrator = EsdfIntegrator(c)
        self.robot_position: np.ndarray | None = None
        self.field: EsdfField | None = None
        self.frames = 0
        self.shifts = 0
        self.dirty = False
        self.stamp_ns = 0
        self.frame_id = "map"
        self._last3d: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # groups, distance, risk group
        self.set_risk_config(risk or RiskConfig())
        self.keyframes = KeyframeMap(self.config)  # the keyframe map-update protocol (keyframes.py)

    # -- inputs ---------------------------------------------------------------------------------
    def set_risk_config(self, risk: RiskConfig) -> None:
        """New obstacle labels, groups and margins; they shape the next ESDF."""
        names = risk.group_names
        unknown = self.config.unknown_group or risk.default_group or names[-1]
        if unknown not in names:
            raise ValueError(f"unknown_group {unknown!r} is not a risk group of {names}")
        self.risk = risk
        self.label_to_group = risk.label_to_group()
        self.margins = risk.margins()
        self.unknown_group_id = risk.group_id(unknown)
        self.dirty = True
        self._last3d = None

    def set_robot_position(self, position: np.ndarray) -> bool:
        """The robot base position (world); recentres the volume if needed. True if it shifted."""
        p = np.asarray(position, dtype=np.float64).reshape(3)
        if not np.isfinite(p).all():
            raise ValueError("robot position is not finite")
        self.robot_position = p
        return self._follow(p)

    def _follow(self, position: np.ndarray) -> bool:
        c = self.config
        target = position + np.asarray(c.centre_offset)
        if self.volume is None:
            self.volume = Volume.centred(c.voxel_size, self.shape, target)
            self.dirty = True
            return False
        if np.linalg.norm(self.volume.centre - target) <= c.recentre_distance:
            return False
        delta = self.volume.shift_to(self.volume.origin_index_for(target))
        if not delta.any():
            return False
        self.tsdf.shift(delta)
        self.semantic.shift(delta)
        self.esdf_integrator.shift(delta)
        self.shifts += 1
        self._last3d = None
        self.dirty = True
        return True

    def integrate(self, points: np.ndarray, confidence: np.ndarray, labels: np.ndarray, T_WC: np.ndarray,
                  stamp_ns: int | None = None, frame_id: str | None = None,
                  intrinsics: tuple[float, float, float, float] | None = None) -> FrameResult:
        """Fuse one pointmap (camera frame) with its pose, confidence and labels; with the pointmap's
        ``intrinsics`` (fx, fy, cx, cy) and ``integration = "projective"``, in one projective pass.

        Raises ``FrameRejected`` (nothing changed) for a non-rigid pose or an absurd pointmap.
        """
        t0 = time.perf_counter()
        check_pose(T_WC)
        check_pointmap(points, confidence, labels, self.config.max_pixels)
        shifted = False
        if self.robot_position is None:
            shifted = self._follow(np.asarray(T_WC, dtype=np.float64)[:3, 3])
        assert self.volume is not None
        if intrinsics is not None and self.config.integration == "projective":
            rays, votes = self.projective_integrator.integrate(self.volume, self.tsdf, self.semantic, points,
                                                               confidence, labels, T_WC, intrinsics)
        else:
            rays = self.tsdf_integrator.integrate(self.volume, self.tsdf, points, confidence, T_WC)
            votes = self.semantic_integrator.integrate(self.volume, self.semantic, points, confidence, labels, T_WC)
        self.frames += 1
        self.dirty = True
        # The ESDF's stamp is the newest integrated data's, kept across re-publications; an
        # unstamped pointmap counts as data of now (its integration), never of a later rebuild.
        self.stamp_ns = int(stamp_ns) if stamp_ns is not None else time.time_ns()
        if frame_id:
            self.frame_id = frame_id
        return FrameResult(rays, votes, shifted, (time.perf_counter() - t0) * 1e3)

    def integrate_frame(self, frame: PerceptionFrame) -> FrameResult:
        if frame.kind is not None:  # new / updated keyframe or tracking frame: see keyframes.py
            return self.keyframes.integrate_frame(self, frame)
        return self.integrate(frame.points, frame.confidence, frame.labels, frame.T_WC,
                              stamp_ns=frame.header.stamp_ns, frame_id=frame.header.frame_id,
                              intrinsics=frame.intrinsics)

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) every kernel before serving, on a scratch volume,
        for writable and read-only (decoded, zero-copy) arrays alike, and the occupancy's."""
        scratch = Volume(self.config.voxel_size, (3, 3, 3))
        tsdf, sem = TsdfLayer(scratch.shape, self.config.truncation), SemanticLayer(scratch.shape)
        pts = np.zeros((2, 2, 3), np.float32)
        pts[..., 2] = self.config.voxel_size
        conf, labels, T = np.ones((2, 2), np.float32), np.zeros((2, 2), np.uint16), np.eye(4)
        for readonly in (False, True):
            arrays = [a.copy() for a in (pts, conf, labels, T)]
            for a in arrays:
                a.flags.writeable = not readonly
            self.tsdf_integrator.integrate(scratch, tsdf, arrays[0], arrays[1], arrays[3])
            self.semantic_integrator.integrate(scratch, sem, arrays[0], arrays[1], arrays[2], arrays[3])
            self.projective_integrator.integrate(scratch, tsdf, sem, arrays[0], arrays[1], arrays[2], arrays[3],
                                                 (2.0, 2.0, 0.5, 0.5))
        c = self.config
        semantic_occupancy(tsdf, sem, self.label_to_group, c.min_weight, c.surface_band, 1, interior="solid",
                           fill_steps=1)
        self.esdf_integrator.warm_up()

    # -- outputs --------------------------------------------------------------------------------
    def occupancy(self) -> np.ndarray:
        """Per-voxel obstacle risk group (0 = not an obstacle) of the current map."""
        c = self.config
        return semantic_occupancy(self.tsdf, self.semantic, self.label_to_group, c.min_weight, c.surface_band,
                                  self.unknown_group_id if c.unknown_is_occupied else 0,
                                  interior=c.obstacle_interior, fill_steps=c.fill_steps,
                                  support_steps=c.support_steps)

    def band_indices(self) -> tuple[int, int, float]:
        """z-voxel range [k_lo, k_hi) whose centres lie in the height band, and the slice's z."""
        assert self.volume is not None
        base = float(self.robot_position[2]) if self.robot_position is not None else 0.0
        lo, hi = base + self.config.band[0], base + self.config.band[1]
        z0, v = float(self.volume.origin[2]), self.volume.voxel_size
        k_lo = math.ceil((lo - z0) / v - 1e-9)
        k_hi = math.floor((hi - z0) / v + 1e-9) + 1
        return k_lo, k_hi, 0.5 * (lo + hi)

    def update_esdf(self) -> MapUpdate | None:
        """Rebuild the field(s) from the current layers; None before the volume exists."""
        if self.volume is None:
            return None
        c = self.config
        out = MapUpdate()
        t0 = time.perf_counter()
        groups = self.occupancy()
        t1 = time.perf_counter()
        out.timings_ms["occupancy"] = (t1 - t0) * 1e3
        out.occupancy = groups
        header = Header(stamp_ns=self.stamp_ns, frame_id=self.frame_id)  # 0: no data integrated yet
        common = dict(voxel_size=self.volume.voxel_size, groups=self.risk.group_names, max_distance=c.max_distance,
                      unknown_is_occupied=c.unknown_is_occupied)
        if c.output in ("2d", "both"):
            k_lo, k_hi, z = self.band_indices()
            dist, grp = self.esdf_integrator.compute_slice(groups, k_lo, k_hi, self.margins)
            origin = self.volume.origin.copy()
            origin[2] = z
            out.slice2d = EsdfGrid(header=header.model_copy(), origin=tuple(origin.tolist()), distance=dist,
                                   risk_group=grp, **common)
            t2 = time.perf_counter()
            out.timings_ms["esdf2d"] = (t2 - t1) * 1e3
            t1 = t2
        if c.output in ("3d", "both"):
            dist, grp = self._esdf3d(groups)
            out.grid3d = EsdfGrid(header=header.model_copy(), origin=tuple(self.volume.origin.tolist()),
                                  distance=dist, risk_group=grp, **common)
            out.timings_ms["esdf3d"] = (time.perf_counter() - t1) * 1e3
        g = out.primary
        self.field = EsdfField.from_grid(g)
        self.dirty = False
        out.timings_ms["total"] = (time.perf_counter() - t0) * 1e3
        return out

    def _esdf3d(self, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The 3-D field, incrementally from the last one when the volume and margins are unchanged."""
        last = self._last3d
        if self.config.esdf_update == "incremental" and last is not None and last[0].shape == groups.shape:
            dist, grp, _ = self.esdf_integrator.update(groups, self.margins, last[0], (last[1], last[2]))
        else:
            dist, grp = self.esdf_integrator.compute(groups, self.margins)
        self._last3d = (groups, dist, grp)
        return dist, grp

    def query(self, points: np.ndarray) -> FieldSample:
        """Distance, gradient, risk group (and in-map flag, ``inside``) of the latest field at world
        points: the filter's field and in-map rule (``fields.answer_query``)."""
        if self.field is None:
            n = np.asarray(points, dtype=np.float64).reshape(-1, 3).shape[0]
            return unknown_sample(n, self.config.max_distance, self.config.unknown_is_occupied)
        return answer_query(self.field, points)


__all__ = ["FrameRejected", "FrameResult", "MapUpdate", "Mapper"]
