"""Configuration of the filter core: which barrier model, its geometry, gains and bounds.

The node's settings (``settings.py``) extend this with timeouts and the risk file; a
simulation that uses the core directly builds a ``FilterConfig`` alone.

Like the mapper's (see ``mapping.config``), the configuration is composed of one parameter
struct per part — ``BarrierParams`` (model and geometry), ``BoundsParams`` (input box) and
``QpParams`` (rate, sampled-data margin, rows, solver) — flat, so every setting keeps its
one name (``--set robot_radius=0.2``, ``config.robot_radius``).
"""

from __future__ import annotations

from typing import Annotated, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field

from .barriers import BarrierModel, DoubleIntegrator, SingleIntegrator, UnicycleLookahead

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Point = tuple[float, float, float]

ModelName = Literal["unicycle", "single2d", "single3d", "double3d"]
P = TypeVar("P", bound=BaseModel)


class BarrierParams(BaseModel):
    """The barrier model and its geometry.

    ``model``: ``unicycle`` (look-ahead point, the LIMO default), ``single2d`` / ``single3d``
    (body-frame velocity control) or ``double3d`` (acceleration control with the HOCBF).
    ``extra_points`` are further body-frame points (x forward, y left, z up; world-frame offsets
    for ``double3d``), each adding one CBF row. ``lambda_v``, ``lambda_w`` weight the unicycle's
    QP; ``k_v`` is the double integrator's velocity-tracking gain.
    """

    model_config = ConfigDict(extra="forbid")

    model: ModelName = "unicycle"
    lookahead_m: Pos = 0.25
    extra_points: list[Point] = Field(default_factory=list, max_length=16)
    robot_radius: NonNeg = 0.15
    lambda_v: Pos = 1.0
    lambda_w: Pos = 0.5
    k_v: Pos = 2.0


class BoundsParams(BaseModel):
    """The input box. Bounds are symmetric: |v| ≤ v_max (per axis for single integrators),
    |ω| ≤ w_max, |v_z| ≤ vz_max, |a_i| ≤ a_max."""

    model_config = ConfigDict(extra="forbid")

    v_max: Pos = 1.0
    w_max: Pos = 2.0
    vz_max: Pos = 0.5
    a_max: Pos = 3.0


class QpParams(BaseModel):
    """The sampled-data QP: control rate, margin δ, predictive rows, solver.

    ``sampled_data_margin`` δ (m) tightens the barrier to h - δ so that h = d - r stays
    non-negative between control instants; ``None`` picks the largest barrier-point speed
    within the bounds times the control period (see ``barriers``).

    ``predictive_rows`` adds, per point, the CBF row with the field's gradient at the point's
    position one period ahead under the reference (see ``filter``): it keeps the filter from
    sliding across the kink of the distance field between two obstacles.
    """

    model_config = ConfigDict(extra="forbid")

    sampled_data_margin: NonNeg | None = None
    rate_hz: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 50.0
    margins_in_filter: bool = False
    predictive_rows: bool = True
    solver: Literal["auto", "active_set", "osqp"] = "auto"


class FilterConfig(QpParams, BoundsParams, BarrierParams):
    """Barrier model and QP of the safety filter: ``BarrierParams``, ``BoundsParams`` and
    ``QpParams`` composed; it builds the barrier model and knows the sampled-data margin."""

    model_config = ConfigDict(extra="forbid")

    @classmethod
    def compose(cls, barrier: BarrierParams | None = None, bounds: BoundsParams | None = None,
                qp: QpParams | None = None) -> FilterConfig:
        parts = (barrier, bounds, qp)
        return cls.model_validate({k: v for p in parts if p is not None for k, v in p.model_dump().items()})

    def part(self, params: type[P]) -> P:
        """One part's own struct, with this configuration's values."""
        return params.model_validate({k: getattr(self, k) for k in params.model_fields})

    barrier = property(lambda self: self.part(BarrierParams), doc="The ``BarrierParams`` part.")
    bounds = property(lambda self: self.part(BoundsParams), doc="The ``BoundsParams`` part.")
    qp = property(lambda self: self.part(QpParams), doc="The ``QpParams`` part.")

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
        if self.model == "unicycle":
            return UnicycleLookahead(self.lookahead_m, self.robot_radius, self.lambda_v, self.lambda_w,
                                     self.v_max, self.w_max, extra)  # type: ignore[arg-type]
        if self.model in ("single2d", "single3d"):
            return SingleIntegrator(2 if self.model == "single2d" else 3, self.robot_radius, self.v_max,
                                    self.vz_max, [(0.0, 0.0, 0.0), *extra], self.w_max)  # type: ignore[list-item]
        return DoubleIntegrator(self.robot_radius, self.a_max, self.k_v, self.dt,
                                [(0.0, 0.0, 0.0), *extra], self.v_max)  # type: ignore[list-item]
