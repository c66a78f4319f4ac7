"""Pydantic models of every message of the wire contract v1 (see DESIGN.md).

Every message map carries ``"schema": "<Name>/1"`` and a ``header``. Unknown extra fields
are ignored (so newer senders stay readable); fields added after v1 are optional with a
default (so older senders stay valid).
"""

from __future__ import annotations

import time
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, ValidationInfo, field_validator, model_validator

from .arrays import ArraySpec

Vec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]
Quat = tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
PosFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]


def now_ns() -> int:
    return time.time_ns()


class Header(BaseModel):
    """Wall-clock stamp (ns since the epoch), frame id and a per-publisher sequence number."""

    model_config = ConfigDict(extra="ignore")

    stamp_ns: Annotated[int, Field(ge=0)] = Field(default_factory=now_ns)
    frame_id: str = "map"
    seq: Annotated[int, Field(ge=0)] = 0


class Message(BaseModel):
    """Base of every wire message. ``SCHEMA`` is the value of the ``"schema"`` key."""

    model_config = ConfigDict(extra="ignore", arbitrary_types_allowed=True)
    SCHEMA: ClassVar[str] = ""

    header: Header = Field(default_factory=Header)

    @classmethod
    def __get_pydantic_json_schema__(cls, core_schema: Any, handler: Any) -> dict:
        schema = handler(core_schema)
        schema = handler.resolve_ref_schema(schema)
        schema.setdefault("properties", {})
        schema["properties"] = {"schema": {"const": cls.SCHEMA}, **schema["properties"]}
        schema["required"] = ["schema", *[r for r in schema.get("required", []) if r != "schema"]]
        if "header" not in schema["required"]:
            schema["required"].append("header")
        return schema


# -- images and perception ---------------------------------------------------------------

RGB8 = ArraySpec("|u1", (None, None, 3))


class Image(Message):
    """An RGB image: ``rgb8`` (uint8 HxWx3 array) or ``jpeg`` (the JPEG file's bytes)."""

    SCHEMA: ClassVar[str] = "Image/1"

    encoding: Literal["rgb8", "jpeg"]
    width: Annotated[int, Field(gt=0)]
    height: Annotated[int, Field(gt=0)]
    data: Annotated[
        Any,
        Field(json_schema_extra={"anyOf": [RGB8.json_schema(), {"type": "string", "contentEncoding": "binary"}]}),
    ]

    @field_validator("data", mode="plain")
    @classmethod
    def _data(cls, value: Any, info: ValidationInfo) -> Any:
        enc, w, h = info.data.get("encoding"), info.data.get("width"), info.data.get("height")
        if enc == "jpeg":
            if not isinstance(value, (bytes, bytearray, memoryview)) or len(value) < 4:
                raise ValueError("jpeg data must be the bytes of a JPEG file")
            return bytes(value)
        arr = ArraySpec("|u1", (h, w, 3)).check(value, info)
        return arr

    intrinsics: tuple[PosFloat, PosFloat, FiniteFloat, FiniteFloat] | None = None
    """Additive: pinhole intrinsics (fx, fy, cx, cy, pixels) of this image's own pixel grid, when the
    camera is calibrated. Set only on images free of lens distortion (the camera node undistorts
    them); ``None``: uncalibrated, or distorted pixels."""


DEPTH16, DEPTH32 = ArraySpec("<f2", (None, None)), ArraySpec("<f4", (None, None))

#: The ``confidence`` of a depth known to be right: a simulator's truth frame, a depth camera's valid
#: pixel. MASt3R's per-observation confidence is 1 + exp(·) ≥ 1 (``Frame.get_average_conf``), so 1 is
#: its least certain pixel, and the mapping's weights are in these units: a surface seen at 1 where
#: the map holds free space shows only after ~9 frames (0.9 s at 10 Hz), at this value after one or
#: two. It is the ``sim`` backend's most confident pixel (a surface seen head-on, close).
CERTAIN_CONFIDENCE = 10.0


class PerceptionFrame(Message):
    """A camera-frame pointmap with pose, per-pixel confidence and ADE20K labels.

    The pointmap comes as ``points`` (HxWx3 float32), or compact as ``depth`` (HxW, z in metres,
    float16 or float32, 0 where nothing was seen) with ``intrinsics``: point = depth · ((u − cx)/fx,
    (v − cy)/fy, 1), the pinhole convention of ``DepthImage`` (``pointmap()`` rebuilds it)."""

    SCHEMA: ClassVar[str] = "PerceptionFrame/1"

    T_WC: Annotated[np.ndarray, ArraySpec("<f8", (4, 4))]
    points: Annotated[np.ndarray, ArraySpec("<f4", (None, None, 3))] | None = None
    """The camera-frame pointmap; ``None`` when the frame carries ``depth`` instead (additive: v1
    senders always send it)."""
    confidence: Annotated[np.ndarray, ArraySpec("<f4", (None, None))]
    labels: Annotated[np.ndarray, ArraySpec("<u2", (None, None))]
    keyframe_id: int
    kind: Literal["keyframe_new", "keyframe_update", "tracking"] | None = None
    """Additive (map-update protocol): ``keyframe_new`` — a keyframe the map has not seen, integrate it;
    ``keyframe_update`` — keyframe ``keyframe_id`` again, re-posed or with a refined pointmap, carrying
    its full pointmap: replace its previous contribution; ``tracking`` — a tracked frame, not integrated
    (its stamp says the map is current). ``None`` (older senders): an independent observation, integrated."""
    intrinsics: tuple[PosFloat, PosFloat, FiniteFloat, FiniteFloat] | None = None
    """Addition: pinhole intrinsics (fx, fy, cx, cy, pixels) of the pointmap's own pixel grid, when
    the backend knows them (sim, calibrated cameras); the mapper then integrates projectively."""
    depth: Annotated[
        Any, Field(json_schema_extra={"anyOf": [DEPTH16.json_schema(), DEPTH32.json_schema(), {"type": "null"}]})
    ] = None
    """Additive: the compact pointmap, z (m) along each pixel's ray, ``<f2`` or ``<f4``, ≥ 0 (0: no
    return), with ``intrinsics`` required; sent instead of ``points`` (a quarter of their bytes in
    float16, whose rounding is ≤ 1 mm up to 4 m and ≤ 2 mm up to 8 m)."""

    @field_validator("depth", mode="plain")
    @classmethod
    def _depth(cls, value: Any, info: ValidationInfo) -> np.ndarray | None:
        if value is None:
            return None
        half = (value.get("dtype") if isinstance(value, dict) else getattr(value, "dtype", None)) in ("<f2", np.float16)
        arr = (DEPTH16 if half else DEPTH32).check(value, info)
        if arr.size and float(arr.min()) < 0.0:
            raise ValueError("depth must be ≥ 0 (0: no return)")
        return arr

    @model_validator(mode="after")
    def _consistent(self) -> PerceptionFrame:
        if self.points is None and self.depth is None:
            raise ValueError("a frame needs points or depth")
        if self.points is not None and self.depth is not None:
            raise ValueError("a frame carries points or depth, not both")
        if self.depth is not None and self.intrinsics is None:
            raise ValueError("depth needs intrinsics")
        hw = self.pixels
        if self.confidence.shape != hw:
            raise ValueError(f"confidence shape {list(self.confidence.shape)} differs from the pointmap's {list(hw)}")
        if self.labels.shape != hw:
            raise ValueError(f"labels shape {list(self.labels.shape)} differs from the pointmap's {list(hw)}")
        return self

    @property
    def pixels(self) -> tuple[int, int]:
        """(H, W) of the pointmap's pixel grid."""
        grid = self.points if self.points is not None else self.depth
        return tuple(grid.shape[:2])  # type: ignore[union-attr,return-value]

    def pointmap(self) -> np.ndarray:
        """The camera-frame pointmap (HxWx3 float32): ``points``, or rebuilt from ``depth`` and
        ``intrinsics`` (the pinhole of ``services.geometry.camera.PinholeCamera``)."""
        if self.points is not None:
            return self.points
        fx, fy, cx, cy = self.intrinsics  # type: ignore[misc]  # the validator requires them with depth
        z = np.asarray(self.depth, np.float32)
        h, w = z.shape
        out = np.empty((h, w, 3), np.float32)
        out[..., 0] = ((np.arange(w, dtype=np.float32) - np.float32(cx)) / np.float32(fx))[None, :] * z
        out[..., 1] = ((np.arange(h, dtype=np.float32) - np.float32(cy)) / np.float32(fy))[:, None] * z
        out[..., 2] = z
        return out


class DepthImage(Message):
    """Additive (``camera/depth``): a depth image registered to the RGB image of the same stamp,
    with its pinhole intrinsics (OpenCV axes: x right, y down, z forward; pixel centres at
    integer coordinates). ``depth`` is z in metres, 0 where the sensor has no return."""

    SCHEMA: ClassVar[str] = "DepthImage/1"

    depth: Annotated[np.ndarray, ArraySpec("<f4", (None, None))]
    fx: PosFloat
    fy: PosFloat
    cx: FiniteFloat
    cy: FiniteFloat


# -- maps -----------------------------------------------------------------------------------


class EsdfGrid(Message):
    """A signed, semantically inflated distance field on a regular grid (nz = 1: a 2-D slice).

    ``distance[i, j, k]`` is the signed distance (m) at the centre of voxel (i, j, k), whose
    position is ``origin + voxel_size * (i, j, k)``; > 0 free, < 0 inside the inflated
    obstacle set, clipped to ``max_distance``. ``risk_group`` is the 1-based id of the
    nearest obstacle's risk group (``groups[id - 1]``), 0 where there is none.
    """

    SCHEMA: ClassVar[str] = "EsdfGrid/1"

    origin: Vec3
    voxel_size: PosFloat
    distance: Annotated[np.ndarray, ArraySpec("<f4", (None, None, None))]
    risk_group: Annotated[np.ndarray, ArraySpec("|u1", (None, None, None))]
    groups: list[str]
    max_distance: PosFloat
    unknown_is_occupied: bool
    observed_free: Annotated[np.ndarray, ArraySpec("|u1", (None, None, None))] | None = None
    """Additive: 1 where the mapper observed the cell's floor free within its ``observed_free_s``
    before the stamp and no obstacle stands in it, else 0 (unknown is not free); None: not kept.
    What an evading robot may retreat into."""

    @model_validator(mode="after")
    def _consistent(self) -> EsdfGrid:
        if self.risk_group.shape != self.distance.shape:
            raise ValueError(
                f"risk_group shape {list(self.risk_group.shape)} differs from distance {list(self.distance.shape)}"
            )
        if self.observed_free is not None and self.observed_free.shape != self.distance.shape:
            raise ValueError(f"observed_free shape {list(self.observed_free.shape)} differs from distance "
                             f"{list(self.distance.shape)}")
        if self.risk_group.size and int(self.risk_group.max()) > len(self.groups):
            raise ValueError(f"risk_group id {int(self.risk_group.max())} has no entry in groups")
        return self

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.distance.shape)  # type: ignore[return-value]


class DistanceQuery(Message):
    """A batch of map-frame points whose distance, gradient and risk group are asked for."""

    SCHEMA: ClassVar[str] = "DistanceQuery/1"

    points: Annotated[np.ndarray, ArraySpec("<f8", (None, 3))]


class DistanceReply(Message):
    """Answer to a ``DistanceQuery``, row for row. ``in_map`` (optional) is False where a
    point lies outside the map (beyond the hull of the ESDF's voxel centres, where the safety
    filter brakes with ``outside_map``); its distance is then ``-max_distance`` if unknown space is
    occupied, else ``max_distance``."""

    SCHEMA: ClassVar[str] = "DistanceReply/1"

    distance: Annotated[np.ndarray, ArraySpec("<f8", (None,))]
    gradient: Annotated[np.ndarray, ArraySpec("<f8", (None, 3))]
    risk_group: Annotated[np.ndarray, ArraySpec("|u1", (None,))]
    in_map: Annotated[np.ndarray, ArraySpec("|b1", (None,))] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> DistanceReply:
        n = self.distance.shape[0]
        rows = [self.gradient.shape[0], self.risk_group.shape[0]]
        if self.in_map is not None:
            rows.append(self.in_map.shape[0])
        if any(r != n for r in rows):
            raise ValueError("distance, gradient, risk_group (and in_map) must have the same number of rows")
        return self


# -- robot ------------------------------------------------------------------------------------


class RobotState(Message):
    """Pose and world-frame velocities of the robot base. Orientation is a unit quaternion xyzw."""

    SCHEMA: ClassVar[str] = "RobotState/1"

    position: Vec3
    orientation: Quat
    linear_velocity: Vec3
    angular_velocity: Vec3

    @field_validator("orientation")
    @classmethod
    def _unit(cls, q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        norm = sum(c * c for c in q) ** 0.5
        if abs(norm - 1.0) > 1e-2:
            raise ValueError(f"orientation must be a unit quaternion, |q| = {norm:.4g}")
        return q

    @property
    def yaw(self) -> float:
        """Heading about +z (rad), for planar robots."""
        x, y, z, w = self.orientation
        return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


class VelocityCommand(Message):
    """Body-frame velocity command (m/s, rad/s) and who produced it."""

    SCHEMA: ClassVar[str] = "VelocityCommand/1"

    linear: Vec3
    angular: Vec3
    source: str
    engaged: bool | None = None
    """Additive: whether the source asks for control (a joystick's dead-man held). ``False``: the
    command does not renew the source's claim in the filter's arbitration (``cmd/ref`` sources with
    priorities, ``ref_sources``), so a lower-priority source takes over once the claim times out;
    ``None`` (older senders, planners): every command claims."""

    @classmethod
    def zero(cls, source: str, **kw: Any) -> VelocityCommand:
        return cls(linear=(0.0, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source=source, **kw)


class SafetyStatus(Message):
    """What the safety filter did on one step and why. ``fallback`` names why it braked
    (``None`` when it did not); ``esdf_age_ms`` is the map's content age (now − its header
    stamp, the newest sensor data in it), -1 before any ESDF has arrived."""

    SCHEMA: ClassVar[str] = "SafetyStatus/1"

    h: FiniteFloat
    risk_group: Annotated[int, Field(ge=0)]
    intervening: bool
    fallback: str | None
    solve_us: NonNegFloat
    esdf_age_ms: FiniteFloat
    # Additive: risk-file changes refused since start (the configuration in force was kept).
    risk_errors: Annotated[int, Field(ge=0)] = 0
    # Additive: publishers seen on map/esdf lately (2 or more: a stuck or rogue second mapper),
    # and maps refused since start (stale or future content, seq backwards, older than in force).
    esdf_publishers: Annotated[int, Field(ge=0)] = 0
    esdf_refused: Annotated[int, Field(ge=0)] = 0
    # Additive: a moving object (or a yielding group: people, animals) asked more than stopping, so
    # the robot stays stopped and waits (it never drives away on its own); and how many tracked
    # objects on a collision course had their own barrier row on this step.
    yielding: bool = False
    object_rows: Annotated[int, Field(ge=0)] = 0
    # Additive: with the filter's opt-in ``evade``, the command is a retreat from someone coming at
    # the stopped robot, into floor the map observed free.
    evading: bool = False
    # Additive: the cmd/ref source the arbitration listens to now (None: no source is live, or a
    # lock holds them all: ``fallback = "locked"``), and the risk configuration in force: its
    # version (0: the built-in defaults; +1 on every change taken, kept across restarts with
    # ``state_dir``) and hash (``RiskConfig.digest``).
    ref_source: str | None = None
    risk_version: Annotated[int, Field(ge=0)] = 0
    risk_hash: str = ""
    # Additive: while perception's map scale is uncertain (``perception/alignment``) the filter reads
    # the field shrunk by ``distance_margin`` (m, at the critical point) and caps the speed at
    # ``speed_cap`` (m/s; None: no cap); ``scale_uncertain`` says so.
    scale_uncertain: bool = False
    distance_margin: NonNegFloat = 0.0
    speed_cap: NonNegFloat | None = None
    # Additive: an Ackermann chassis could not steer the filtered command's curvature, so the command
    # is the one it will drive (its tightest circle at that speed), which the filter passed unchanged.
    steering_limited: bool = False


class Alignment(Message):
    """Perception's similarity from its SLAM world into the odometry frame (REP 105's ``odom``,
    metric): a SLAM point x lands at ``scale · R(rotation) · x + translation``. ``scale_sigma`` is the
    scale's relative standard deviation, ``residual`` the RMS distance (m) between the camera positions
    mapped by it and odometry's over the window, ``pairs`` how many there were, ``baseline`` their
    spread (m), ``source`` where the scale came from (``floor``: the floor plane and the camera's height,
    before the robot has moved; ``motion``: camera positions against odometry, Umeyama; ``fused``: both),
    ``converged`` whether ``scale_sigma`` is below perception's threshold."""

    SCHEMA: ClassVar[str] = "Alignment/1"

    scale: PosFloat
    rotation: Quat
    translation: Vec3
    scale_sigma: NonNegFloat
    residual: NonNegFloat
    pairs: Annotated[int, Field(ge=0)] = 0
    baseline: NonNegFloat = 0.0
    source: Literal["none", "floor", "motion", "fused"] = "none"
    converged: bool = False


class CommandLock(Message):
    """Additive (``cmd/lock``): a lock on the ``cmd/ref`` arbitration, as twist_mux's lock topics.
    While ``locked`` (or, with a lock timeout, while its source is silent) every source below the
    lock's priority is held and the filter brakes (``fallback = "locked"``). Each ``source`` holds
    its own lock; only the same source releases it."""

    SCHEMA: ClassVar[str] = "CommandLock/1"

    locked: bool
    source: str


class NavGoal(Message):
    """Waypoints for the navigator (map frame), a reach tolerance, and whether to loop."""

    SCHEMA: ClassVar[str] = "NavGoal/1"

    waypoints: Annotated[np.ndarray, ArraySpec("<f8", (None, 3))]
    tolerance: PosFloat
    loop: bool

    @field_validator("waypoints")
    @classmethod
    def _some(cls, w: np.ndarray) -> np.ndarray:
        if w.shape[0] < 1:
            raise ValueError("at least one waypoint is required")
        return w


# -- additions beyond wire contract v1 (additive) -------------------------------------------


class NodeStatus(Message):
    """Per-node counters on ``{prefix}/{robot}/status/{service}``: per key, messages received,
    rejected as invalid, dropped by a latest-value queue, and published; handler timing."""

    SCHEMA: ClassVar[str] = "NodeStatus/1"

    service: str
    pid: int = 0
    uptime_s: NonNegFloat = 0.0
    received: dict[str, int] = Field(default_factory=dict)
    invalid: dict[str, int] = Field(default_factory=dict)
    dropped: dict[str, int] = Field(default_factory=dict)
    published: dict[str, int] = Field(default_factory=dict)
    errors: int = 0
    handler_ms_p50: NonNegFloat = 0.0
    handler_ms_p99: NonNegFloat = 0.0
    handler_ms_max: NonNegFloat = 0.0
    extra: dict[str, FiniteFloat] = Field(default_factory=dict)
    # Additive: the risk configuration in force in a node that uses one (mapping, safety-filter):
    # version and hash as in ``SafetyStatus``; None in the others.
    risk_version: Annotated[int, Field(ge=0)] | None = None
    risk_hash: str | None = None


class LimoDiagnostics(Message):
    """Chassis and link health, published by the ``limo`` bridge on ``{prefix}/{robot}/limo/diagnostics``.

    ``vehicle_state``, ``control_mode`` and ``motion_mode`` are as reported by the chassis
    (``-1`` before its first system-state frame); ``feedback_age_ms`` is -1 before any feedback."""

    SCHEMA: ClassVar[str] = "LimoDiagnostics/1"

    port: str
    connected: bool
    battery_v: FiniteFloat
    error_bits: Annotated[int, Field(ge=0)]
    vehicle_state: int
    control_mode: int
    motion_mode: int
    command_mode_confirmed: bool
    mode_mismatch: bool
    frames_ok: Annotated[int, Field(ge=0)]
    frames_bad: Annotated[int, Field(ge=0)]
    bytes_skipped: Annotated[int, Field(ge=0)]
    reconnects: Annotated[int, Field(ge=0)]
    watchdog_stops: Annotated[int, Field(ge=0)]
    commands: Annotated[int, Field(ge=0)]
    odometry_jumps: Annotated[int, Field(ge=0)] = 0
    feedback_age_ms: FiniteFloat = -1.0


class TrackedObject(BaseModel):
    """One moving-capable obstacle (person, animal) tracked across map updates, world frame."""

    model_config = ConfigDict(extra="ignore")

    id: Annotated[int, Field(ge=0)]
    """Stable while the object is tracked; never reused by one publisher."""
    label: Annotated[int, Field(ge=0)]
    """ADE20K class index of the object's segment."""
    risk_group: Annotated[int, Field(ge=0)]
    """1-based risk group (as ``EsdfGrid.risk_group``), 0 = none."""
    position: Vec3
    """Centre of the object's occupied voxels (m)."""
    velocity: Vec3
    """Estimated velocity (m/s); zero for an object judged static."""
    radius: NonNegFloat
    """Horizontal extent about ``position`` (m), before inflation."""
    age_ms: NonNegFloat
    """How long ago the object was last observed, relative to the header stamp (0: in the newest frame)."""
    tracked_ms: NonNegFloat = 0.0
    """How long the object has been tracked: a young track's velocity is less certain."""


class TrackedObjects(Message):
    """Additive (``map/objects``): the mapper's tracked people and animals, stamped like the ESDF they
    were extracted from, so that a filter or planner can add the obstacle's motion (∂h/∂t)."""

    SCHEMA: ClassVar[str] = "TrackedObjects/1"

    objects: list[TrackedObject] = Field(default_factory=list)


class SimActor(BaseModel):
    """Ground truth of one simulated object that can move (world frame)."""

    model_config = ConfigDict(extra="ignore")

    name: str
    label: Annotated[int, Field(ge=0)]
    """ADE20K class index."""
    position: Vec3
    """Centre of the object's footprint at floor height (m)."""
    velocity: Vec3
    """m/s."""
    radius: NonNegFloat
    """Horizontal radius of the object's cylinder (m)."""
    height: NonNegFloat = 0.0


class SimActors(Message):
    """Additive, simulation only (``sim/actors``): the ground-truth poses and velocities of the scene's
    moving objects, stamped like the camera image of the same simulation step."""

    SCHEMA: ClassVar[str] = "SimActors/1"

    actors: list[SimActor] = Field(default_factory=list)


MESSAGE_TYPES: tuple[type[Message], ...] = (
    Image,
    PerceptionFrame,
    DepthImage,
    EsdfGrid,
    DistanceQuery,
    DistanceReply,
    RobotState,
    VelocityCommand,
    SafetyStatus,
    NavGoal,
    NodeStatus,
    CommandLock,
    LimoDiagnostics,
    TrackedObjects,
    SimActors,
    Alignment,
)
