"""The mapping core's configuration: one object the ``Mapper`` is built from.

As in nvblox (``nvblox/mapper/mapper_params.h``: ``MapperParams`` holds the
``ProjectiveIntegratorParams``, ``OccupancyIntegratorParams``, ``EsdfIntegratorParams``, ...),
each stage has its own parameter struct — ``VolumeParams``, ``TsdfParams``,
``OccupancyParams``, ``EsdfParams``, ``DynamicParams`` (how people and animals decay),
``ObjectParams`` (the tracker of moving people and animals, ``objects.py``) — and ``MapperConfig``
composes them. The composition is
flat (``MapperConfig`` is each of them), so a setting keeps one short name everywhere
(``--set truncation=0.2``, ``RISKFIELD_TRUNCATION``, ``config.truncation``); ``config.tsdf``
etc. give one stage its own struct, and ``MapperConfig.compose`` builds one from the parts.
Each integrator is built from its own struct alone (the TSDF, semantic, projective and keyframe
integrators from ``TsdfParams``, the ESDF's from ``EsdfParams``) plus the few derived numbers it is handed
(the voxel size, the surface band), as nvblox's integrators take only their own parameters.

Defaults follow the authors' release (5 cm voxels in a rolling local volume that follows the
robot) but for the volume's shape, made for a ground robot (``VolumeParams.half_extent``).
Distances are metres, weights are sums of per-pixel confidences (the pointmap's confidence is the
observation weight).
"""

from __future__ import annotations

from typing import Annotated, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

from riskfield.protocol import ade20k

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


class VolumeParams(BaseModel):
    """The rolling volume: voxel size, extent and how it follows the robot."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    voxel_size: Annotated[float, Field(gt=0.005, le=2.0)] = 0.05
    """Edge (m) of a voxel of the rolling volume."""
    half_extent: tuple[Pos, Pos, Pos] = (3.0, 3.0, 1.25)
    """Half size (m) of the rolling volume along x, y, z. A ground robot's: a person is in the map, and
    tracked, once within 3 m along both floor axes, soon enough for the robot to stop short of the
    path of someone crossing towards it at 1.5 m/s (``riskfield bench crowd``); 1.25 m up and down
    holds the 2-D slice's band and what hangs over it. 121 × 121 × 51 voxels at 5 cm, fewer than the
    authors' cube's 101³; the slice's 121² cells keep ``map/esdf`` within the off-board link's 1 MB/s
    (``riskfield bench link``). A flying robot wants a taller volume."""
    centre_offset: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)
    """Volume centre relative to the robot (e.g. raise it for a ground robot)."""
    recentre_distance: NonNeg = 0.25
    """The volume shifts (keeping the overlap) once the robot is this far from its centre."""
    max_voxels: Annotated[int, Field(gt=0)] = 16_000_000
    """Largest voxel count the volume may have: a setting that would need more is refused at start."""

    @model_validator(mode="after")
    def _voxel_count(self) -> VolumeParams:
        n = 1
        for h in self.half_extent:
            n *= 2 * round(h / self.voxel_size) + 1
        if n > self.max_voxels:
            raise ValueError(f"the volume has {n} voxels, over max_voxels = {self.max_voxels}")
        return self

    @property
    def shape(self) -> tuple[int, int, int]:
        """Voxels per axis: an odd count so the robot sits on a voxel centre."""
        return tuple(2 * round(h / self.voxel_size) + 1 for h in self.half_extent)  # type: ignore[return-value]


#: Parameters that chose a reference implementation, removed: setting one (a node setting,
#: ``MappingSettings.REMOVED``, or a core parameter) is an error that names what replaced it.
REMOVED_SETTINGS: dict[str, str] = {
    "esdf_update": "removed: the 3-D grid is updated incrementally (esdf_incremental chooses how) and "
                   "recomputed in full only where it has no previous grid (the first map, a moved volume, "
                   "new margins)",
    "esdf_kernel": "removed: the 3-D field always runs the compiled passes (esdf_kernels); the numpy path "
                   "is the tests' oracle (tests/oracles/esdf.py)",
    "esdf_edt": "removed: the distance transforms are always the compiled ones (distance_transform); the "
                "edt package is the tests' oracle (tests/oracles/esdf.py)",
    "carve_stride": "removed: it strided the per-pixel carving rays of integration 'ray', now the tests' oracle "
                    "(tests/oracles/tsdf.py); every merged ray carves (integration 'merged') and the projective "
                    "pass carves every voxel in view in front of the surface",
}
_TSDF_REMOVED = ("carve_stride",)
_ESDF_REMOVED = ("esdf_update", "esdf_kernel", "esdf_edt")

def _refuse_removed(data: dict, keys: tuple[str, ...]) -> None:
    """Raise for the first of the removed parameters ``keys`` that ``data`` sets, naming what replaced it."""
    for key in keys:
        if key in data:
            raise ValueError(f"{key!r} is not a parameter: {REMOVED_SETTINGS[key]}")


class TsdfParams(BaseModel):
    """TSDF integration of a pointmap (projective, weighted by confidence; free-space carving)."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    truncation: Pos = 0.15
    """TSDF truncation distance (m); the band updated around each observed surface point."""
    max_weight: Pos = 50.0
    """Cap of a voxel's accumulated weight, so the map can still follow moving people and pets:
    the TSDF is a running mean over the last few frames' worth of confidence. A person who stood
    3 s clears 2–9 frames after leaving at confidence 10–1.5 (``tests/mapping/test_present.py``).
    20 clears in 1–4 but lets the carving rays of the ray-based integration (frames without intrinsics,
    e.g. ``mast3r``) erode surfaces seen up close. Under the keyframe protocol it caps the present
    layer; the keyframes' own sums are uncapped (``keyframes.py``)."""
    min_confidence: NonNeg = 0.1
    """Pixels whose confidence is below this are skipped."""
    min_depth: NonNeg = 0.05
    """Points nearer than this (m, along the ray) are skipped."""
    max_depth: Pos = 6.0
    """Points farther than this (m, along the ray) only carve free space up to it."""
    pixel_stride: Annotated[int, Field(ge=1, le=64)] = 2
    """Integrate every n-th pixel in each image direction (a 5 cm voxel at 2.5 m spans ~8 px)."""
    integration: Literal["projective", "merged"] = "projective"
    """``projective``: frames with intrinsics project the voxels in view into the pointmap, TSDF and
    label votes in one pass (``projective_integrator.py``), other frames take ``merged``;
    ``merged``: every frame casts one ray per voxel its points fall in (``tsdf_integrator.py``)."""
    block_size: Annotated[int, Field(ge=2, le=64)] = 8
    """``projective``: voxels per block edge; only blocks meeting the view frustum are visited."""
    integration_threads: Annotated[int, Field(ge=1, le=64)] = 1
    """``projective``: threads over the blocks. 1 by default: a frame takes ~1.5 ms on one core of
    the 2-core development machine, and with 2 OpenMP threads on cores other processes keep busy
    it took 70–80 ms (every parallel loop waits for its slowest thread)."""
    carve: bool = True
    """Also update free space from the camera to the surface band (clears moved obstacles)."""
    carve_weight: Annotated[float, Field(gt=0, le=100.0)] = 1.0
    """Weight of a free-space observation relative to its pixel's confidence."""
    max_free_weight: Pos = 3.0
    """Free-space observations raise a voxel's weight only up to this (a surface observation up to
    ``max_weight``). A surface appearing in space long seen free is then not drowned: its mean
    crosses into the surface band once its weight is about 3× this (the band is a quarter of the
    truncation). Measured (``tests/mapping/test_present.py``, 10 Hz frames): a person appears in
    2 frames at the ``sim`` backend's confidence ≈ 7 of a fresh keyframe, 3 at 4, 5 at 2 (a cap of
    50 would take 2 s at 7). Lower shows single-frame outliers as obstacles."""
    max_pixels: Annotated[int, Field(gt=0)] = 4_000_000
    """Frames with more pixels than this are rejected as absurd."""

    @model_validator(mode="before")
    @classmethod
    def _removed_tsdf(cls, data: object) -> object:
        if isinstance(data, dict):
            _refuse_removed(data, _TSDF_REMOVED)
            if data.get("integration") == "ray":
                raise ValueError("integration 'ray' is removed: frames with intrinsics take 'projective', the "
                                 "others 'merged' (one ray per voxel the frame's points fall in); one ray per pixel "
                                 "is the tests' oracle of both (tests/oracles/tsdf.py)")
        return data

    @model_validator(mode="after")
    def _depth_range(self) -> TsdfParams:
        if self.min_depth >= self.max_depth:
            raise ValueError("min_depth must be below max_depth")
        return self


class OccupancyParams(BaseModel):
    """Which voxels are obstacles: TSDF surface support, semantic labels' band, unknown space."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    min_weight: NonNeg = 0.5
    """Surface support needs at least this TSDF weight."""
    surface_band_vox: Annotated[float, Field(gt=0, le=3.0)] = 0.75
    """A voxel supports the surface when |tsdf| ≤ this × voxel_size; labels are voted in the same band."""
    obstacle_interior: Literal["solid", "shell"] = "solid"
    """``solid``: observed voxels behind a surface (weight ≥ ``min_weight``, TSDF < 0) belong to the
    obstacle, with the risk group of their nearest labelled surface voxel, so the distance is
    negative inside; ``shell``: only the surface band is occupied (obstacles are hollow). See
    ``occupancy.py``."""
    unobserved_behind_surface: Literal["free", "solid"] = "solid"
    """Never-observed voxels behind an obstacle's observed interior (beyond the truncation):
    ``solid`` fills them up to ``behind_surface_depth`` along the viewing direction (the shadow
    of the surface; observed voxels stop it), so a box, a person or a wall seen from one side is
    negative inside however deep; ``free`` leaves them free (an obstacle is then only
    ``truncation`` deep, and deeper inside the field is positive with its gradient pointing in)."""
    behind_surface_depth: Annotated[float, Field(ge=0, le=5.0, allow_inf_nan=False)] = 5.0
    """Depth (m) of the ``solid`` fill. 5 m spans the default map (4.3 m from its centre to a corner): the
    shadow an observed obstacle casts is solid up to the first observed voxel or the map's edge, so an
    object seen only end-on is negative all the way through, with the gradient pointing out of the
    shadow (sideways, up, or back to the seen face), never further in. The price: the never-observed
    space behind an obstacle (a doorway's part hidden by its jamb, the floor behind a sofa) reads closed
    until a camera looks into it; any ray through it reopens it at once. A shallower fill (e.g. 0.5 m)
    keeps such gaps open beyond that depth but leaves deeper objects positive inside past τ + the
    depth, with the gradient pointing further in."""
    unobserved_below_obstacle: Literal["free", "solid"] = "solid"
    """Never-observed voxels straight below an obstacle (``solid``, with the ``solid`` fill behind
    surfaces): up to ``below_obstacle_depth`` they join it, so an object whose top was seen at a
    grazing angle and whose sides were not is not a lid over free space (``occupancy.py``)."""
    below_obstacle_depth: Annotated[float, Field(ge=0, le=5.0, allow_inf_nan=False)] = 1.0
    """Depth (m) of the ``solid`` fill below obstacles; any observed voxel ends it earlier."""
    unknown_is_occupied: bool = False
    """Treat never-observed voxels as obstacles (of ``unknown_group``)."""
    unknown_group: str | None = None
    """Risk group of unknown voxels; ``None`` → the risk config's default group, else its last group."""


class EsdfParams(BaseModel):
    """The risk-inflated ESDF: clipping, inflation rule, output form and EDT threads."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    max_distance: Annotated[float, Field(gt=0, le=100.0)] = 2.0
    """Distances are clipped to [-max_distance, max_distance]."""
    inflation: Literal["exact", "dilate"] = "exact"
    """``exact``: distance = min over groups of (d_group − margin_group), margins exact in metres.
    ``dilate``: the paper-faithful variant, occupancy dilated by whole voxels, then the ESDF."""
    output: Literal["2d", "3d", "both"] = "2d"
    """``2d``: the ground-robot slice on ``map/esdf``; ``3d``: the 3-D grid on ``map/esdf``;
    ``both``: the slice on ``map/esdf`` and the 3-D grid on ``map/esdf3d``."""
    band: tuple[Finite, Finite] = (0.10, 0.60)
    """Height band (m, relative to the robot base z) the 2-D slice covers."""
    threads: Annotated[int, Field(ge=1, le=64)] = 1
    """Cores the distance transforms run on. 1 by default, as ``integration_threads``: beside the
    stack's other processes a parallel loop waits for its slowest thread. With one other busy
    process on the 2-core development machine, the 2-D slice's transform (101²) took 17 ms on 2
    threads against 0.14 ms on 1, and the 3-D grid's (101³) 22–44 ms against 27 (``edt`` of 1 %
    random sites); in the demo the 2-D ESDF update's p90 was 65 ms. More where cores are spare."""
    esdf_incremental: Literal["box", "wave"] = "box"
    """How the 3-D grid is updated after an edit: ``box`` recomputes the changed voxels' box grown by
    the reach (exact); ``wave`` keeps nearest-site maps and moves only the voxels whose value changes
    (``esdf_wave``; 26-neighbour propagation: rare digital misses of a few mm far from obstacles, see
    there). The whole grid is computed where there is no previous one (the first map, a moved volume,
    new margins)."""

    @model_validator(mode="before")
    @classmethod
    def _removed(cls, data: object) -> object:
        if isinstance(data, dict):
            _refuse_removed(data, _ESDF_REMOVED)
        return data

    @model_validator(mode="after")
    def _band_order(self) -> EsdfParams:
        if self.band[0] > self.band[1]:
            raise ValueError(f"band {list(self.band)}: the lower height must not exceed the upper")
        return self


class DynamicParams(BaseModel):
    """How the map follows a changing world: the present layer of the keyframe protocol and the
    decay of people and animals (see ``mapper.py``, "The map shows the present")."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    dynamic_labels: tuple[str, ...] = ("person", "animal")
    """ADE20K classes that move by themselves: their voxels decay once no current frame has seen
    them at a surface for ``dynamic_persist_s``; other classes (furniture, walls) never decay."""
    dynamic_persist_s: NonNeg = 3.0
    """T: how long a person or animal stays in the map after a current frame last saw it (out of
    view, occluded). 3 s: a LIMO at its 1 m/s passes a person beside it (where the forward camera
    does not look) within 1.5 s and turns 90° in about 2 s, so a person it just saw stays while it
    could still turn or back into them; a walker at 1.5 m/s has moved 4.5 m by then, so a longer
    memory mostly keeps a ghost."""
    dynamic_max_weight: Pos = 5.0
    """Cap of the weight of a person's or animal's voxels (their labelled surface and the unlabelled
    inside the last occupancy gave their group; applied with the decay, every 0.1 s
    of frame time, to the running means: the default mode's TSDF and the keyframe protocol's
    present layer, not the keyframes' removable sums; other voxels keep ``max_weight``): what moves
    by itself is a running mean over about a frame, so the space it leaves clears within a few
    frames even where the rays through it are of low confidence. With the common cap of 50, a
    person who stood 3 s at 1 m (confidence ≈ 7 from the ``sim`` backend) took 25 frames to clear
    against a far wall seen at confidence ≈ 1.8; with 5, 3 frames."""
    dynamic_moving_persist_s: NonNeg = 0.5
    """T_w: how long a person's or animal's voxels outlive the last frame that saw them, where the
    tracker (``map/objects``) places no one standing and sees no one now (``DynamicDecay``,
    ``ObjectTracker.protected``): a walker who left the view, the place a person stood before
    walking off, the top of a person too close for the camera's view. They are not there any more
    (at 1 m/s, 0.5 m on after 0.5 s: past their own radius and the high-risk margin), and holding
    them for T kept the robot below 80 % of its reference for 2.5–2.7 s after people had left its
    way. Where someone was last seen standing, T (``dynamic_persist_s``) holds. Needs
    ``object_tracking``."""
    repose_tolerance: Pos = 0.025
    """A ``keyframe_update`` whose pose moved more than this (m at the camera, or the angle times
    ``max_depth``) re-poses the world the present layer was built in: the present layer is cleared
    and rebuilt from the next frames (default: half a 5 cm voxel)."""

    @model_validator(mode="after")
    def _labels(self) -> DynamicParams:

        for name in self.dynamic_labels:
            try:
                ade20k.index(name)
            except KeyError as exc:
                raise ValueError(f"dynamic_labels: {exc.args[0]}") from None
        return self

    @property
    def dynamic_indices(self) -> list[int]:
        """ADE20K indices of ``dynamic_labels``."""

        return [ade20k.index(n) for n in self.dynamic_labels]


class ObjectParams(BaseModel):
    """The tracker of movable obstacles (``objects.py``; which labels move is ``DynamicParams.dynamic_labels``):
    how their footprints are segmented, associated across map updates and turned into velocities (``map/objects``)."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    object_tracking: bool = True
    """Track movable obstacles after each map update and publish them on ``map/objects``."""
    object_merge_gap: Annotated[float, Field(ge=0, le=2.0, allow_inf_nan=False)] = 0.2
    """Footprint parts up to this far apart (m; along the grid axes, rounded up to an even number of
    voxels; diagonally a little less) are one object: a person's two legs in the height band are one
    person, and so are two people side by side this close."""
    object_min_area: NonNeg = 0.01
    """Smaller footprints (m², 4 voxels of 5 cm) are left out as label noise."""
    object_max_count: Annotated[int, Field(ge=1, le=1000)] = 32
    """At most this many objects (the largest footprints) per update: the output stays bounded."""
    object_gate: NonNeg = 0.3
    """A footprint continues a track of the same label if its centre is within this (m) plus
    ``object_max_speed`` × the time since the track was last seen of the track's last position
    (no faster object can be farther); the nearest (to the constant-velocity prediction) wins."""
    object_fresh_s: NonNeg = 0.05
    """A footprint's columns seen more than this (s) before its newest sighting (the layers' ``hit``
    clock) are not in that sighting: behind a walker, they are the trail the map still holds
    (``objects.py``). Below one frame period: one frame's view."""
    object_window_s: Pos = 0.5
    """Velocity: least squares over the track's centres of the last this many seconds (frame stamps)."""
    object_min_samples: Annotated[int, Field(ge=2, le=100)] = 3
    """A track's velocity stays zero until it has this many observations in the window."""
    object_max_speed: Pos = 3.0
    """Estimated speeds are capped at this (m/s): faster than a running person is a segmentation or
    association error, not motion."""
    object_deadband: NonNeg = 0.1
    """Speeds below this (m/s) read zero: a static person's footprint jitter (a voxel over the window
    is 0.1 m/s) is not motion, so a static scene has ∂h/∂t = 0."""
    object_body_radius: Pos = 0.4
    """What ``ObjectTracker.protected`` keeps around a person or animal (m, before ``object_gate``)
    at most: a footprint wider than a body (1.6 m was seen) is a person joined with the trail or
    the ghost the map still holds, which must not be kept for ``dynamic_persist_s``."""
    object_expire_s: Pos = 1.0
    """A track unobserved for longer than this (s) is dropped; until then it is published with its
    last position and velocity and a growing ``age_ms``."""


class FloorParams(BaseModel):
    """Which floor counts as observed free (``free_floor``): what an evading robot may retreat into."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    observed_free_s: Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)] = 5.0
    """s: a floor cell a camera ray crossed without meeting a surface counts as observed free for
    this long (what an evading robot may retreat into); 0: the layer is not kept."""
    observed_free_stride: Annotated[int, Field(ge=1, le=64)] = 8
    """Pixel stride of the rays that mark the floor observed free."""


P = TypeVar("P", bound=BaseModel)


class MapperConfig(FloorParams, ObjectParams, DynamicParams, EsdfParams, OccupancyParams, TsdfParams, VolumeParams):
    """Everything that shapes the map: the stages' parameter structs, composed (see the module
    doc). Group names, labels and margins come from the ``RiskConfig`` instead (hot-reloadable),
    not from here."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    @classmethod
    def compose(cls, volume: VolumeParams | None = None, tsdf: TsdfParams | None = None,
                occupancy: OccupancyParams | None = None, esdf: EsdfParams | None = None,
                dynamic: DynamicParams | None = None, objects: ObjectParams | None = None,
                floor: FloorParams | None = None) -> MapperConfig:
        parts = (volume, tsdf, occupancy, esdf, dynamic, objects, floor)
        return cls.model_validate({k: v for p in parts if p is not None for k, v in p.model_dump().items()})

    def part(self, params: type[P]) -> P:
        """One stage's own struct, with this configuration's values."""
        return params.model_validate({k: getattr(self, k) for k in params.model_fields})

    volume = property(lambda self: self.part(VolumeParams), doc="The ``VolumeParams`` part.")
    tsdf = property(lambda self: self.part(TsdfParams), doc="The ``TsdfParams`` part.")
    occupancy = property(lambda self: self.part(OccupancyParams), doc="The ``OccupancyParams`` part.")
    esdf = property(lambda self: self.part(EsdfParams), doc="The ``EsdfParams`` part.")
    dynamic = property(lambda self: self.part(DynamicParams), doc="The ``DynamicParams`` part.")
    objects = property(lambda self: self.part(ObjectParams), doc="The ``ObjectParams`` part.")
    floor = property(lambda self: self.part(FloorParams), doc="The ``FloorParams`` part.")

    @property
    def surface_band(self) -> float:
        return self.surface_band_vox * self.voxel_size

    @property
    def fill_steps(self) -> int:
        """Voxel steps of the never-observed fill behind surfaces (0 unless ``solid``)."""
        if self.obstacle_interior != "solid" or self.unobserved_behind_surface != "solid":
            return 0
        return int(self.behind_surface_depth / self.voxel_size + 1e-9)

    @property
    def support_steps(self) -> int:
        """Voxel steps of the never-observed fill below obstacles (0 unless both fills are ``solid``)."""
        if self.fill_steps == 0 or self.unobserved_below_obstacle != "solid":
            return 0
        return int(self.below_obstacle_depth / self.voxel_size + 1e-9)
