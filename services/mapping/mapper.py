"""The Mapper: the rolling volume, its layers and the integrators, composed (Algorithm 1).

    integrate(frame)   pointmap + pose + confidence → TSDF layer      (TsdfIntegrator)
                       labels + confidence          → semantic layer  (SemanticIntegrator, vote rule)
                       with the frame's intrinsics: both in one projective pass (ProjectiveIntegrator)
    update_esdf()      TSDF surface + solid interior + labels → semantic occupancy (occupancy.py)
                       → semantically inflated signed ESDF, 3-D and/or the 2-D slice (EsdfOutput,
                       esdf_output.py: the 3-D grid incrementally from the last one while volume and
                       margins stay)
    decay()            people's and animals' voxels unseen for long enough leave the layers
                       (DynamicDecay, before each occupancy)
    query(points)      distance, gradient, risk group of the latest field (EsdfOutput.query)

The volume follows the robot: ``set_robot_position`` (from ``RobotState``) recentres it
once the robot is ``recentre_distance`` from its centre, keeping the overlapping voxels.
Before any state arrives it follows the camera of the incoming frames instead, and the
2-D slice's height band is measured from z = 0.

The mapper has no I/O; it is driven by the mapping node, the benchmark and the tests.

**The map shows the present.** Every frame that carries the camera's current view —
a frame without ``kind``, a ``tracking`` frame, a ``keyframe_new`` — reaches the map, as the
authors' release integrates every current frame:

* Frames without ``kind`` are integrated into the TSDF (``tsdf``/``semantic``) as before.
* Under the keyframe protocol (``keyframes.py``) the keyframes' contributions stay exact and
  removable in ``tsdf``, and every current frame is *also* integrated into the **present layer**
  (``present``, ``present.py``): a running mean capped at ``max_weight``, i.e. the last few
  frames (the keyframes' own sums are uncapped, so they could not follow). Where the two disagree
  on whether a voxel is an obstacle (a person who came or left), or only the present layer has
  seen it, the occupancy reads the present layer; elsewhere the keyframes' exact, re-posable map.
  A tracked frame's geometry is thus attributed to no keyframe: it *decays* as newer frames
  overwrite it (the cap), and a ``keyframe_update`` that re-poses the world (pose moved over
  ``repose_tolerance``) clears the present layer, which the next frames rebuild in the corrected
  frame of reference.
* Free-space observations raise a voxel's weight only up to ``max_free_weight``, so a surface
  that appears in space long seen free shows within a few frames.
* People and animals (``dynamic_labels``) decay: a voxel of theirs at or behind a surface that no
  current frame has seen so (``TsdfLayer.hit``) for ``dynamic_persist_s`` is cleared (checked
  every 0.1 s of frame time); furniture and walls never decay. nvblox does the same with time:
  its ``FreespaceIntegrator`` keeps per voxel when it was last seen occupied (dynablox; objects
  moving into long-free space are dynamic) and its dynamic (human) occupancy layer and, optionally,
  the TSDF decay every update (``OccupancyDecayIntegrator``, ``TsdfDecayIntegrator``:
  ``nvblox/include/nvblox/integrators/{freespace,occupancy_decay,tsdf_decay}_integrator.h``). Here the
  decay is by label (one camera gives labels, not a second depth-masked layer) and after a fixed
  time, so a person's persistence does not depend on how often they were seen.

The ESDF's stamp is the newest frame whose geometry changed the map: a frame that integrates
nothing (every pixel unusable), a ``keyframe_update`` (a re-sent keyframe: refined content whose
data the tracked frames already stamped) or an ignored update never advances it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial

import numpy as np

from riskfield.protocol import Header, PerceptionFrame, RiskConfig
from riskfield.protocol import field as field_query

from ..fields import FieldSample
from .config import FloorParams, MapperConfig
from .decay import DecayLayers, DynamicDecay
from .esdf_output import EsdfOutput, MapUpdate
from .free_floor import FreeFloorIntegrator, FreeFloorLayer
from .keyframes import NEW, UPDATE, KeyframeData, KeyframeMap
from .layers import NEVER, SemanticLayer, TsdfLayer
from .objects import MapReading
from .occupancy import OccupancyRule, semantic_occupancy
from .pointmap import FrameRejected, check_pointmap, check_pose
from .present import PresentLayer
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


class FutureFrame(FrameRejected):
    """A frame stamped later than the receiver's clock allows (``integrate_frame``)."""


class Mapper:
    """Semantic TSDF → semantic occupancy → inflated signed ESDF, on a rolling local volume."""

    def __init__(self, config: MapperConfig | None = None, risk: RiskConfig | None = None):
        self.config = config or MapperConfig()
        c = self.config
        self.shape = c.shape
        self.volume: Volume | None = None
        self.tsdf = TsdfLayer(self.shape, c.truncation)
        self.semantic = SemanticLayer(self.shape)
        # nvblox's pattern: each integrator gets its own parameter struct (config.py), nothing else
        self.tsdf_integrator = TsdfIntegrator(c.tsdf)
        self.semantic_integrator = SemanticIntegrator(c.tsdf, c.surface_band)
        self.projective_integrator = ProjectiveIntegrator(c.tsdf, c.surface_band)
        #: occupancy → the published grids and the queried field (esdf_output.py)
        self.output = EsdfOutput(c.esdf, c.voxel_size, c.unknown_is_occupied)
        #: the floor seen free (free_floor.py): what an evading robot may retreat into
        self.free_floor = FreeFloorLayer(self.shape)
        self.free_floor_integrator = FreeFloorIntegrator(c.part(FloorParams), c.truncation, c.min_confidence,
                                                         c.min_depth, c.max_depth)
        self.robot_position: np.ndarray | None = None
        self.frames = 0
        self.shifts = 0
        self.dirty = False
        self.stamp_ns = 0
        self.frame_id = "map"
        self.set_risk_config(risk or RiskConfig())
        self.keyframes = KeyframeMap.of(self.config)  # the keyframe map-update protocol (keyframes.py)
        #: the keyframe protocol's present layer (present.py)
        self.present = PresentLayer(self.shape, c.truncation, c.min_weight, c.surface_band)
        self.read: tuple[TsdfLayer, SemanticLayer] = (self.tsdf, self.semantic)  # what the last occupancy read
        # Frame time on the layers' ``hit`` clock: ms since the first frame (int32 spans 24 days).
        self.epoch_ns: int | None = None
        self.now_ms = 0
        self._groups: tuple[np.ndarray, np.ndarray] | None = None  # the last occupancy, at its origin index
        #: people's and animals' voxels fade (decay.py); the node sets its ``protected`` from the tracker
        self.dynamic = DynamicDecay(c.dynamic, c.surface_band, c.object_gate)

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
        self.output.forget()

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
        self.present.shift(delta)
        self.output.shift(delta)
        self.free_floor.shift(delta)
        self.shifts += 1
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
        shifted = self._accept(points, confidence, labels, T_WC)
        # An unstamped pointmap counts as data of now (its integration), never of a later rebuild.
        stamp = int(stamp_ns) if stamp_ns is not None else time.time_ns()
        now_ms = self.clock(stamp or time.time_ns())
        rays, votes = self._integrate_into(self.tsdf, self.semantic, self._integrators(), points, confidence,
                                           labels, T_WC, intrinsics, now_ms)
        self.observe_floor(points, confidence, T_WC, now_ms)
        self.changed(stamp if rays > 0 else None, frame_id)
        return FrameResult(rays, votes, shifted, (time.perf_counter() - t0) * 1e3)

    def _accept(self, points: np.ndarray, confidence: np.ndarray, labels: np.ndarray, T_WC: np.ndarray) -> bool:
        """Check a frame (``FrameRejected``: nothing changed) and, before any robot state, follow
        its camera. True if the volume shifted."""
        check_pose(T_WC)
        check_pointmap(points, confidence, labels, self.config.max_pixels)
        if self.robot_position is None:
            return self._follow(np.asarray(T_WC, dtype=np.float64)[:3, 3])
        return False

    def _integrators(self) -> tuple[TsdfIntegrator, SemanticIntegrator, ProjectiveIntegrator]:
        return self.tsdf_integrator, self.semantic_integrator, self.projective_integrator

    def _integrate_into(self, tsdf: TsdfLayer, semantic: SemanticLayer,
                        integrators: tuple[TsdfIntegrator, SemanticIntegrator, ProjectiveIntegrator],
                        points: np.ndarray, confidence: np.ndarray, labels: np.ndarray, T_WC: np.ndarray,
                        intrinsics: tuple[float, float, float, float] | None, now_ms: int) -> tuple[int, int]:
        assert self.volume is not None
        ray, sem, proj = integrators
        if intrinsics is not None and self.config.integration == "projective":
            return proj.integrate(self.volume, tsdf, semantic, points, confidence, labels, T_WC, intrinsics,
                                  now_ms)
        rays = ray.integrate(self.volume, tsdf, points, confidence, T_WC, now_ms)
        return rays, sem.integrate(self.volume, semantic, points, confidence, labels, T_WC)

    def observe_floor(self, points: np.ndarray, confidence: np.ndarray, T_WC: np.ndarray, now_ms: int) -> int:
        """A current frame's rays → the floor seen free (``free_floor``); the cells marked."""
        if self.volume is None or self.config.observed_free_s == 0:
            return 0
        base = self._base_z()
        return self.free_floor_integrator.integrate(self.volume, self.free_floor, points, confidence, T_WC, base,
                                                    base + self.config.band[1], now_ms)

    def clock(self, stamp_ns: int) -> int:
        """The frame time ``stamp_ns`` on the layers' ``hit`` clock (ms since the first frame);
        also the mapper's ``now_ms`` when it is the newest yet."""
        if self.epoch_ns is None:
            self.epoch_ns = int(stamp_ns)
        ms = int(np.clip((int(stamp_ns) - self.epoch_ns) // 1_000_000, NEVER + 1, np.iinfo(np.int32).max))
        self.now_ms = max(self.now_ms, ms)
        return ms

    def changed(self, stamp_ns: int | None, frame_id: str | None = None) -> None:
        """The map changed; with data of ``stamp_ns`` (None: no new data, e.g. a re-sent keyframe,
        so the ESDF keeps the stamp of the newest data it shows)."""
        if stamp_ns is None:
            return
        self.frames += 1
        self.dirty = True
        self.stamp_ns = int(stamp_ns)
        if frame_id:
            self.frame_id = frame_id

    def integrate_present(self, frame: PerceptionFrame, points: np.ndarray | None = None) -> tuple[int, int]:
        """A current frame under the keyframe protocol → the present layer (module doc); ``points``:
        its pointmap when already rebuilt (``PerceptionFrame.pointmap``)."""
        assert self.volume is not None
        tsdf, semantic = self.present.layers()
        stamp = int(frame.header.stamp_ns) or time.time_ns()
        pts = frame.pointmap() if points is None else points
        return self._integrate_into(tsdf, semantic, self._integrators(), pts, frame.confidence, frame.labels,
                                    frame.T_WC, frame.intrinsics, self.clock(stamp))

    def clear_present(self) -> None:
        """The keyframes were re-posed: the present layer was built in the old frame of reference."""
        if self.present.clear():
            self.dirty = True

    def decay(self) -> int:
        """People's and animals' voxels unseen for long enough leave the layers (``decay.py``);
        at most every 0.1 s of frame time. Returns the count."""
        layers = [DecayLayers(self.tsdf, self.semantic, running_mean=not len(self.keyframes))]
        if self.present.tsdf is not None and self.present.semantic is not None:
            layers.append(DecayLayers(self.present.tsdf, self.present.semantic, running_mean=True))
        groups = self._groups
        at_origin = groups is not None and self.volume is not None and (groups[1] == self.volume.origin_index).all()
        n = self.dynamic.decay(self.now_ms, layers, self.volume, groups[0] if at_origin else None,
                               self.label_to_group)
        if n:
            self.dirty = True
        return n

    def layers(self) -> tuple[TsdfLayer, SemanticLayer]:
        """What the occupancy reads: the keyframes' TSDF, overlaid by the present layer where the
        two disagree (``PresentLayer.over``)."""
        return self.present.over(self.tsdf, self.semantic)

    def integrate_frame(self, frame: PerceptionFrame, latest_ns: int | None = None) -> FrameResult:
        """Fuse a frame; with ``latest_ns`` (the receiver's wall clock plus its tolerance), a frame
        stamped after it raises ``FutureFrame`` before anything changes: taken, its stamp would
        ratchet ``now_ms`` ahead (the dynamic labels would then decay at once and every later frame
        look old) and make the ESDF's stamp a time that has not come."""
        if latest_ns is not None and frame.header.stamp_ns > latest_ns:
            raise FutureFrame(f"stamped {(frame.header.stamp_ns - latest_ns) / 1e9:.3f} s after this clock allows")
        if frame.kind is not None:  # new / updated keyframe or tracking frame: see keyframes.py
            return self._integrate_keyframe_protocol(frame)
        return self.integrate(frame.pointmap(), frame.confidence, frame.labels, frame.T_WC,
                              stamp_ns=frame.header.stamp_ns, frame_id=frame.header.frame_id,
                              intrinsics=frame.intrinsics)

    def _integrate_keyframe_protocol(self, frame: PerceptionFrame) -> FrameResult:
        """A frame with ``kind``: the keyframe bookkeeping (``self.keyframes``) changes the TSDF's
        contributions; a current frame (``keyframe_new``, ``tracking``) also reaches the present layer."""
        t0 = time.perf_counter()
        kind, kid = frame.kind, int(frame.keyframe_id)
        points = frame.pointmap()  # a compact frame's depth, rebuilt once
        shifted = self._accept(points, frame.confidence, frame.labels, frame.T_WC)
        assert self.volume is not None
        stamp = int(frame.header.stamp_ns)
        rays = votes = 0
        if self.keyframes.admit(kind, kid):
            assert kind in (NEW, UPDATE)
            content = KeyframeData(points, frame.confidence, frame.labels, frame.T_WC)
            rays, votes, reposed = self.keyframes.integrate(self.volume, self.tsdf, self.semantic, kind, kid, content,
                                                            self.clock(stamp or time.time_ns()))
            if reposed:  # what was seen free was seen in the old frame of reference
                self.clear_present()
                self.free_floor.clear()
            self.dirty = True
            if kind == UPDATE:
                self.frames += 1
        if kind != UPDATE:  # new keyframes and tracked frames show the camera's present view
            rays, votes = self.integrate_present(frame, points)
            self.observe_floor(points, frame.confidence, frame.T_WC, self.clock(stamp or time.time_ns()))
            self.changed(stamp if rays > 0 else None, frame.header.frame_id)
        self.keyframes.count(kind)
        return FrameResult(rays, votes, shifted, (time.perf_counter() - t0) * 1e3)

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) every kernel before serving, on a scratch volume,
        for writable and read-only (decoded, zero-copy) arrays alike, the floor seen free's and the occupancy's."""
        scratch = Volume(self.config.voxel_size, (3, 3, 3))
        tsdf, sem = TsdfLayer(scratch.shape, self.config.truncation), SemanticLayer(scratch.shape)
        pts = np.zeros((2, 2, 3), np.float32)
        pts[..., 2] = self.config.voxel_size
        conf, labels, T = np.ones((2, 2), np.float32), np.zeros((2, 2), np.uint16), np.eye(4)
        # writable, decoded (read-only), and a compact frame's: its rebuilt pointmap writable, the rest decoded
        for readonly in ((False,) * 4, (True,) * 4, (False, True, True, True)):
            arrays = [a.copy() for a in (pts, conf, labels, T)]
            for a, ro in zip(arrays, readonly, strict=True):
                a.flags.writeable = not ro
            self.tsdf_integrator.integrate(scratch, tsdf, arrays[0], arrays[1], arrays[3])
            self.semantic_integrator.integrate(scratch, sem, arrays[0], arrays[1], arrays[2], arrays[3])
            self.projective_integrator.integrate(scratch, tsdf, sem, arrays[0], arrays[1], arrays[2], arrays[3],
                                                 (2.0, 2.0, 0.5, 0.5))
        self.free_floor_integrator.integrate(scratch, FreeFloorLayer(scratch.shape), pts, conf, T, 0.0, 1.0, 0)
        c = self.config
        semantic_occupancy(tsdf, sem, self.label_to_group,
                           OccupancyRule(c.min_weight, c.surface_band, 1, interior="solid", fill_steps=1))
        self.output.integrator.warm_up()
        field_query.warm_up()  # the query service's and the object tracker's

    # -- outputs --------------------------------------------------------------------------------
    def occupancy(self) -> np.ndarray:
        """Per-voxel obstacle risk group (0 = not an obstacle) of the current map."""
        c = self.config
        self.decay()
        tsdf, semantic = self.read = self.layers()
        rule = OccupancyRule(c.min_weight, c.surface_band, self.unknown_group_id if c.unknown_is_occupied else 0,
                             c.obstacle_interior, c.fill_steps, c.support_steps)
        groups = semantic_occupancy(tsdf, semantic, self.label_to_group, rule)
        if self.volume is not None:
            self._groups = (groups, self.volume.origin_index.copy())
        return groups

    def reading(self, occupancy: np.ndarray) -> MapReading | None:
        """What the object tracker reads of this update, whose occupancy is ``occupancy``; None
        before the first frame placed the volume."""
        if self.volume is None:
            return None
        k_lo, k_hi, _ = self.band_indices()
        tsdf, semantic = self.read  # the layers the occupancy was made of
        return MapReading(
            occupancy=occupancy, band=(k_lo, k_hi), origin=self.volume.origin, voxel_size=self.volume.voxel_size,
            label=semantic.label, tsdf=tsdf.tsdf, weight=tsdf.weight, min_weight=self.config.min_weight,
            hit=self.tsdf.hit, present_hit=None if self.present.tsdf is None else self.present.tsdf.hit,
            label_to_group=self.label_to_group, stamp_ns=self.stamp_ns, now_ms=self.now_ms)

    def _base_z(self) -> float:
        """The robot base's height, which the slice's band and the floor are measured from (0 before any state)."""
        return float(self.robot_position[2]) if self.robot_position is not None else 0.0

    def band_indices(self) -> tuple[int, int, float]:
        """z-voxel range [k_lo, k_hi) whose centres lie in the height band, and the slice's z."""
        assert self.volume is not None
        return self.output.band_indices(self.volume, self._base_z())

    def update_esdf(self) -> MapUpdate | None:
        """Rebuild the field(s) from the current layers; None before the volume exists."""
        if self.volume is None:
            return None
        c = self.config
        t0 = time.perf_counter()
        groups = self.occupancy()
        occupancy_ms = (time.perf_counter() - t0) * 1e3
        header = Header(stamp_ns=self.stamp_ns, frame_id=self.frame_id)  # 0: no data integrated yet
        free = partial(self.free_floor.observed_free, self.now_ms, c.observed_free_s) if c.observed_free_s else None
        out = self.output.build(groups, self.volume, header, self.margins, self.risk.group_names, self._base_z(),
                                free)
        out.timings_ms = {"occupancy": occupancy_ms, **out.timings_ms,
                          "total": (time.perf_counter() - t0) * 1e3}
        self.dirty = False
        return out

    def query(self, points: np.ndarray) -> FieldSample:
        """Distance, gradient, risk group (and in-map flag) of the latest field at world points."""
        return self.output.query(points)


__all__ = ["FrameRejected", "FrameResult", "MapUpdate", "Mapper"]
