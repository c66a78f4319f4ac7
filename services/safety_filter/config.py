"""Configuration of the filter core: which barrier model, its geometry, gains and bounds.

The node's settings (``settings.py``) extend this with timeouts and the risk file; a
simulation that uses the core directly builds a ``FilterConfig`` alone.

Like the mapper's (see ``mapping.config``), the configuration is composed of one parameter
struct per part — ``BarrierParams`` (model and geometry), ``BoundsParams`` (input box),
``QpParams`` (rate, sampled-data margin, rows, solver) and ``MotionParams`` (moving obstacles) —
flat, so every setting keeps its one name (``--set robot_radius=0.2``, ``config.robot_radius``).
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from riskfield.protocol import ade20k
from riskfield.protocol.platforms import LIMO, PlanarPlatform

from ..fields.grid import Interpolation
from .barriers import BarrierModel, Braking, DoubleIntegrator, SingleIntegrator, UnicycleLookahead, disc_cover

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Point = tuple[float, float, float]

ModelName = Literal["unicycle", "single2d", "single3d", "double3d"]
P = TypeVar("P", bound=BaseModel)


#: The AgileX LIMO's footprint (m), the unicycle model's default body (``protocol.platforms.LIMO``).
LIMO_LENGTH, LIMO_WIDTH = LIMO.length, LIMO.width


def platform_bounds(p: PlanarPlatform) -> dict[str, float]:
    """A ground robot's input bounds for the unicycle model: its speed, yaw rate and deceleration."""
    return {"v_max": p.max_linear, "w_max": p.max_angular, "a_max": p.max_accel}


def platform_footprint(p: PlanarPlatform, discs: int = 3) -> Footprint:
    """A ground robot's body rectangle as the filter's footprint (``discs`` discs on its medial axis)."""
    return Footprint(shape="rectangle", length=p.length, width=p.width, discs=discs)


#: The input bounds a model defaults to where the configuration sets none, over ``BoundsParams``'
#: (a generic robot's): the unicycle is the LIMO, whose limits live in ``protocol.platforms``.
MODEL_BOUNDS: dict[str, dict[str, float]] = {"unicycle": platform_bounds(LIMO)}


class Footprint(BaseModel):
    """The robot's body, covered by discs that each add a CBF row (``barriers.disc_cover``).

    ``rectangle`` / ``capsule``: ``length`` × ``width`` centred on the body origin, x forward,
    covered by ``discs`` discs on the medial axis (robots with a heading; not ``double3d``, which
    has no attitude). ``sphere``: one ball of ``radius`` at the origin (``None``: the config's
    ``robot_radius``). ``none``: only the control points (the look-ahead point for the
    unicycle): the paper's filter, unprotected sides and rear.
    """

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    shape: Literal["rectangle", "capsule", "sphere", "none"]
    length: Pos = LIMO_LENGTH
    width: Pos = LIMO_WIDTH
    radius: Pos | None = None
    discs: Annotated[int, Field(ge=1, le=8)] = 3


class BarrierParams(BaseModel):
    """The barrier model and its geometry.

    ``model``: ``unicycle`` (look-ahead point, the LIMO default), ``single2d`` / ``single3d``
    (body-frame velocity control) or ``double3d`` (acceleration control with the HOCBF).
    ``extra_points`` are further body-frame points (x forward, y left, z up; world-frame offsets
    for ``double3d``), each adding one CBF row. ``lambda_v``, ``lambda_w`` weight the unicycle's
    QP; ``k_v`` is the double integrator's velocity-tracking gain.

    ``footprint`` (``None``: the model's default — the LIMO rectangle for the unicycle, a sphere
    of ``robot_radius`` otherwise) adds the body's disc cover to the control points.
    ``barrier`` picks the double integrator's barrier: ``braking`` (the default: keep the
    braking distance φ(s) at ``brake_fraction`` · a_max, feasible under the bounds) or ``hocbf``
    (the paper's eq. 14 as written, which ignores |a_i| ≤ a_max). ``brake_speed_floor`` s₀ (m/s)
    is where φ turns from linear to the braking parabola; ``None`` (default) takes a_b/k₂ of each
    row's risk group (k₂ the faster root of s² + α₁ s + α₂). Below s₀ the braking barrier is then
    the paper's HOCBF (h_b = h + ḣ/k₂), above it the robot can still stop within the bounds; on
    the safety benchmark (v ≤ 0.5 m/s < a_b/k₂ = 0.7 m/s) it collides as often as ``hocbf``, and a
    fixed s₀ = 0.1 m/s with ℓ = 2 cm more often: its fast approach rides the map's surface within
    millimetres, and the map reads a few millimetres to centimetres long. A fixed s₀ keeps the
    input coefficient ≥ s₀/a_b (``DoubleIntegrator``). ``brake_rate_length`` ℓ (m) shapes the class-K function
    κ h_b (1 + h_b/ℓ): linear near the boundary, steeper with clearance (fewer relaxed steps at
    the distance field's ridges, a faster approach); ``inf`` (default): linear.
    """

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    model: ModelName = "unicycle"
    """unicycle: the look-ahead point (the LIMO); single2d / single3d: body-frame velocity control; double3d:
    acceleration control with the HOCBF."""
    lookahead_m: Pos = 0.25
    """unicycle: distance (m) of the controlled point ahead of the axle."""
    extra_points: list[Point] = Field(default_factory=list, max_length=16)
    """Further body-frame points (x forward, y left, z up; world-frame offsets for double3d), one CBF row each."""
    robot_radius: NonNeg = 0.15
    """Radius (m) of each control point's ball: the barrier is h = d - robot_radius."""
    lambda_v: Pos = 1.0
    """unicycle: QP weight of a change of the forward speed."""
    lambda_w: Pos = 0.5
    """unicycle: QP weight of a change of the yaw rate."""
    k_v: Pos = 2.0
    """double3d: gain of the velocity tracking that turns a velocity reference into an acceleration."""
    footprint: Footprint | None = None
    """The body's disc cover added to the control points; None: the LIMO rectangle for the unicycle, a sphere of
    robot_radius otherwise."""
    barrier: Literal["braking", "hocbf"] = "braking"
    """double3d: braking keeps the braking distance within the bounds (feasible); hocbf is the paper's eq. 14 as
    written."""
    brake_fraction: Annotated[float, Field(gt=0, le=1)] = 0.7
    """braking barrier: the deceleration it plans with, as a fraction of a_max (a_b = brake_fraction a_max)."""
    brake_rate_length: Annotated[float, Field(gt=0)] = math.inf
    """braking barrier: length (m) of the class-K function k h (1 + h / length); inf: linear."""
    brake_speed_floor: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    """braking barrier: speed (m/s) where the braking distance turns from linear to a parabola; None: a_b / k2 of
    each row's risk group."""


class BoundsParams(BaseModel):
    """The input box. Bounds are symmetric: |v| ≤ v_max (per axis for single integrators),
    |ω| ≤ w_max, |v_z| ≤ vz_max, |a_i| ≤ a_max. For velocity-controlled models ``a_max`` is the
    platform's deceleration: it caps the first-order gains at 2 a_max / v_point_max so the robot
    can shed any speed the CBF allows within h (``barriers``).

    The defaults here are a generic robot's; a model of a real platform takes that platform's
    limits instead where none is set (``MODEL_BOUNDS``: the ``unicycle`` is the LIMO, so 1 m/s,
    2 rad/s and 1.5 m/s² from ``protocol.platforms.LIMO``)."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    v_max: Pos = 1.0
    """|speed| bound (m/s), per axis for the single integrators; the unicycle's default is the LIMO's."""
    w_max: Pos = 2.0
    """|yaw rate| bound (rad/s); the unicycle's default is the LIMO's."""
    vz_max: Pos = 0.5
    """|vertical speed| bound (m/s), single3d and double3d."""
    a_max: Pos = 3.0
    """|acceleration| bound (m/s^2); for velocity-controlled models the platform's deceleration, which caps the
    gains at 2 a_max / v_max."""
    steering: Literal["differential", "ackermann"] = "differential"
    """unicycle: how the chassis turns. ackermann (the LIMO bridge's mode 1): it drives no circle tighter than the
    platform's minimum turning radius and does not turn below its min_steering_speed (protocol.platforms), so the
    filter passes on only a command it has certified as the chassis will drive it (supervisor)."""

    @property
    def steering_limit(self) -> tuple[float, float] | None:
        """(max curvature 1/m, min steering speed m/s) of an Ackermann unicycle (the LIMO's); None: it turns freely."""
        return (LIMO.max_curvature, LIMO.min_steering_speed) if self.steering == "ackermann" else None


class QpParams(BaseModel):
    """The sampled-data QP: control rate, margin δ, predictive rows, the field's interpolation.

    ``sampled_data_margin`` δ (m) tightens the barrier to h - δ so that h = d - r stays
    non-negative between control instants; ``None`` picks the largest barrier-point speed
    within the bounds times the control period (see ``barriers``).

    ``predictive_rows`` adds, per point, the CBF row with the field's gradient at the point's
    position one period ahead under the reference (see ``filter``): it keeps the filter from
    sliding across the kink of the distance field between two obstacles.

    ``interpolation`` is how the filter reads an ``EsdfField`` (``services/fields/spline.py``;
    the paper's ``trilinear`` with finite differences, ``catmull_rom``, ``bspline`` or
    ``bspline_smooth``, the default: C², never more than h²/6 ∂²d (≈ 2-3 mm) above the true
    distance and below it at ridges, where the interpolating kernels overshoot by up to 8 mm;
    its Hessian is continuous and, off the ridges, as small as the geometry's).
    ``map_margin_voxels`` adds that many voxels of a gridded field (``EsdfField.voxel_size``; 0
    for analytic fields and point clouds) to δ: the ESDF locates a surface that no ray hit
    face-on only to within a voxel. A projective TSDF gives a voxel whose centre lies just
    inside an object the depth of the background seen past the object's edge, so an
    unobserved face (a bed's side seen only from above) reads up to one voxel further than it
    is: 3.6 cm on 5 cm voxels in the safety benchmark, more than the sampled-data δ = v_max T
    (2.5 cm at 20 Hz) the filter settles to. Half a voxel on top of δ keeps the settled
    clearance ≥ one voxel.
    ``slack``: when the QP is infeasible, solve it with every row relaxed to what the backup
    (maximal braking along the gradient) achieves, instead of braking blindly (``filter``).
    """

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    sampled_data_margin: NonNeg | None = None
    """Margin delta (m) that keeps h >= 0 between control instants; None: the largest point speed within the bounds
    times the control period."""
    map_margin_voxels: NonNeg = 0.5
    """Voxels of a gridded field added to delta: the ESDF places a surface no ray hit face-on only to within a
    voxel."""
    rate_hz: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 50.0
    """Control rate: a step (and cmd/safe) at least this often."""
    margins_in_filter: bool = False
    """Subtract each risk group's margin in the filter, for a field whose distances do not include it already (the
    mapping's ESDF does)."""
    predictive_rows: bool = True
    """Add per point the CBF row with the gradient one period ahead under the reference (no sliding across the
    field's kinks)."""
    interpolation: Interpolation = "bspline_smooth"
    """How the ESDF grid is read: bspline_smooth (C2, exact derivatives), bspline, catmull_rom, or the paper's
    trilinear with finite differences."""
    slack: bool = True
    """An infeasible QP is solved with every row relaxed to what maximal braking along the gradient achieves,
    instead of braking blindly."""



class MotionParams(BaseModel):
    """Moving obstacles (``map/objects``) and yielding (``model``'s module docstring): every tracked
    object on a collision course is its own barrier row, with its own velocity, predicted from its
    observation to the instant the command takes effect; the rows of moving objects and of the
    groups that yield may slow and stop the robot, never push it. A track's velocity counts only
    once it is fast, old and fresh enough and its recent observations agree (``motion``), so a
    noisy estimate of a standing person adds nothing.

    The collision course (``model.object_course``): within ``collision_horizon_s`` the object,
    moving on with its velocity and uncertain by ``object_speed_sigma`` · t, comes inside its
    group's margin of the robot's body, with the body moving on as the reference asks or braking
    to rest. 1.5 s at σ = 0.15 m/s (between the tracker's velocity error per axis, 0.06 m/s from its
    median and 0.28 m/s RMS with its lag at stops and turns: ``riskfield bench crowd``) grows a walker's
    reach by 0.23 m: a person walking past at a body gap of 0.5 m stays out (0.5 - 0.15 - 0.23 -
    δ > 0), one walking at 1.2 m/s is seen 1.8 m ahead of the contact, more than the LIMO needs to
    stop from 1 m/s (0.33 m at 1.5 m/s²) with the pipeline's latency."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    object_motion: bool = Field(default=True, description=(
        "each tracked object on map/objects on a collision course adds its own barrier row, with its "
        "own velocity; false: the static barrier, the field alone (the crowd benchmark's baseline)"))
    object_speed_deadband: NonNeg = Field(default=0.2, description=(
        "m/s: a tracked speed below this counts as standing; the velocity ramps in fully at twice it "
        "(continuous, so a speed near the threshold cannot switch the barrier on and off)"))
    object_speed_cap: Pos = Field(default=2.5, description=(
        "m/s: tracked speeds are capped here (a person runs at most ~2.5 m/s indoors; a larger "
        "estimate is noise that would brake for nothing)"))
    object_evidence: Annotated[int, Field(ge=1, le=10)] = Field(default=3, description=(
        "observations of a track whose velocities must agree: a speed counts only as far as each of "
        "them shows it along the newest direction (motion.TrackEvidence; 1: the newest alone). At the "
        "map's 10 Hz, 3 costs a walker who turns 0.2 s before the new direction counts fully"))
    object_young_ms: NonNeg = Field(default=300.0, description=(
        "ms: a track younger than this counts with the fraction tracked_ms / object_young_ms of its velocity"))
    object_stale_ms: Pos = Field(default=500.0, description=(
        "ms: an object not observed for longer than this (its age_ms) adds no motion"))
    object_speed_sigma: NonNeg = Field(default=0.15, description=(
        "m/s: the tracked velocity's uncertainty; a row takes the worst velocity within it (towards the "
        "robot) and the collision course grows the object's reach by sigma · t"))
    collision_horizon_s: Annotated[float, Field(gt=0, le=10, allow_inf_nan=False)] = Field(default=1.5, description=(
        "s: how far ahead a moving object's course is followed: only an object that comes inside its "
        "margin of the robot's body within this adds a row"))
    command_delay_s: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = Field(default=0.06, description=(
        "s: from the filter's step to the command taking effect (a control period, the bridge and the "
        "chassis): tracks are predicted from their observation to then"))
    object_sweep_s: Annotated[float, Field(ge=0, le=5, allow_inf_nan=False)] = Field(default=1.0, description=(
        "s: an object's row keeps the robot out of the capsule its body sweeps along its velocity in this "
        "time, not only out of where it is: the robot stops short of a crossing person's path (0: the body alone)"))
    max_object_rows: Annotated[int, Field(ge=1, le=16)] = Field(default=8, description=(
        "moving objects on a collision course that get a row, the soonest first"))
    yield_labels: list[str] = Field(default_factory=lambda: ["person", "animal"], description=(
        "ADE20K labels whose risk groups yield: the ESDF's rows there may slow and stop the robot but "
        "never push it (no recovery drive away from a person); empty: every group keeps the static "
        "barrier's recovery"))
    evade: bool = Field(default=False, description=(
        "opt-in: retreat from a moving object on a collision course with the stopped robot, at most "
        "evade_speed and evade_distance, only into floor the map observed free (evade.py); false: the "
        "robot stays stopped and lets it pass"))
    evade_speed: Annotated[float, Field(gt=0, le=2, allow_inf_nan=False)] = Field(default=0.3, description=(
        "m/s: the speed of a retreat"))
    evade_distance: Annotated[float, Field(gt=0, le=10, allow_inf_nan=False)] = Field(default=0.5, description=(
        "m: the farthest a retreat goes while one threat lasts"))
    evade_lookahead_s: Annotated[float, Field(gt=0, le=5, allow_inf_nan=False)] = Field(default=1.0, description=(
        "s: the footprint a retreat sweeps in this time must lie in observed-free floor, clear of obstacles"))

    @model_validator(mode="after")
    def _known_labels(self) -> MotionParams:
        unknown = [n for n in self.yield_labels if n not in ade20k.CLASSES]
        if unknown:
            raise ValueError(f"yield_labels: {unknown} are not ADE20K labels")
        return self


class FilterConfig(MotionParams, QpParams, BoundsParams, BarrierParams):
    """Barrier model and QP of the safety filter: ``BarrierParams``, ``BoundsParams``, ``QpParams``
    and ``MotionParams`` composed; it builds the barrier model and knows the sampled-data margin."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    @classmethod
    def compose(cls, barrier: BarrierParams | None = None, bounds: BoundsParams | None = None,
                qp: QpParams | None = None, motion: MotionParams | None = None) -> FilterConfig:
        # Only what each part sets: a part's defaults are the composed config's, except the
        # bounds a platform's model takes from the platform (``MODEL_BOUNDS``).
        parts = (barrier, bounds, qp, motion)
        return cls.model_validate({k: v for p in parts if p is not None
                                   for k, v in p.model_dump(exclude_unset=True).items()})

    @model_validator(mode="after")
    def _the_platforms_bounds(self) -> FilterConfig:
        for key, value in MODEL_BOUNDS.get(self.model, {}).items():
            if key not in self.model_fields_set:
                setattr(self, key, value)
        return self

    @model_validator(mode="after")
    def _steering_is_a_ground_robots(self) -> FilterConfig:
        if self.steering != "differential" and self.model != "unicycle":
            raise ValueError(f"steering {self.steering!r} is a wheeled robot's: model {self.model!r} has no chassis")
        return self

    def part(self, params: type[P]) -> P:
        """One part's own struct, with this configuration's values."""
        return params.model_validate({k: getattr(self, k) for k in params.model_fields})

    barrier_params = property(lambda self: self.part(BarrierParams), doc="The ``BarrierParams`` part.")
    bounds_params = property(lambda self: self.part(BoundsParams), doc="The ``BoundsParams`` part.")
    qp_params = property(lambda self: self.part(QpParams), doc="The ``QpParams`` part.")
    motion_params = property(lambda self: self.part(MotionParams), doc="The ``MotionParams`` part.")

    def body(self) -> Footprint:
        """The footprint in force (the model's default when not configured)."""
        if self.footprint is not None:
            return self.footprint
        if self.model == "unicycle":
            return platform_footprint(LIMO)
        return Footprint(shape="sphere")

    def _discs(self) -> tuple[list[tuple[float, float, float]], list[float]]:
        fp = self.body()
        if fp.shape == "none":
            return [], []
        if fp.shape == "sphere":
            return [(0.0, 0.0, 0.0)], [fp.radius if fp.radius is not None else self.robot_radius]
        if self.model == "double3d":
            raise ValueError("double3d has no heading: its footprint is a sphere")
        o, r = disc_cover(fp.length, fp.width, fp.discs, capsule=fp.shape == "capsule")
        return [tuple(float(v) for v in p) for p in o], r.tolist()  # type: ignore[misc]

    @model_validator(mode="after")
    def _footprint_fits_the_model(self) -> FilterConfig:
        fp = self.footprint
        if self.model == "double3d" and fp is not None and fp.shape in ("rectangle", "capsule"):
            raise ValueError("double3d has no heading: its footprint is a sphere (or none)")
        return self

    @property
    def dt(self) -> float:
        return 1.0 / self.rate_hz

    def margin(self, model: BarrierModel) -> float:
        """The sampled-data margin δ: as configured, else the largest barrier-point speed × T."""
        if self.sampled_data_margin is not None:
            return self.sampled_data_margin
        return model.max_point_speed() * self.dt

    def build_model(self) -> BarrierModel:
        extra = [tuple(p) for p in self.extra_points]
        pts, radii = self._discs()
        if self.model == "unicycle":
            body = (np.array(pts).reshape(-1, 3), np.array(radii)) if pts else None
            return UnicycleLookahead(self.lookahead_m, self.robot_radius, self.lambda_v, self.lambda_w,
                                     self.v_max, self.w_max, extra, body)  # type: ignore[arg-type]
        if not pts:  # no body: the centre point with robot_radius
            pts, radii = [(0.0, 0.0, 0.0)], [self.robot_radius]
        pts = [*pts, *extra]  # type: ignore[list-item]
        radii = np.array([*radii, *[self.robot_radius] * len(extra)])  # type: ignore[assignment]
        if self.model in ("single2d", "single3d"):
            return SingleIntegrator(2 if self.model == "single2d" else 3, radii, self.v_max,
                                    self.vz_max, pts, self.w_max)  # type: ignore[arg-type]
        braking = Braking(self.barrier, self.brake_fraction, self.brake_rate_length, self.brake_speed_floor)
        return DoubleIntegrator(radii, self.a_max, self.k_v, self.dt, pts, self.v_max,  # type: ignore[arg-type]
                                braking)
