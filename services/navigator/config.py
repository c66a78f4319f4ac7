"""Configuration of the navigator: which robot model, CLF gains and limits, timing."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from riskfield.protocol.platforms import PlanarPlatform, SpatialPlatform, platform

from .clf import PointMassCLF, UnicycleCLF

#: The platform a model drives when none is named.
MODEL_PLATFORM = {"unicycle": "limo", "double_integrator": "point_mass"}


class NavigatorConfig(BaseModel):
    """``model = "unicycle"``: planar LIMO-like robot, command ``(v, 0, 0) / (0, 0, ω)``.
    ``model = "double_integrator"``: 3-D point robot; the command is the CLF's velocity
    demand ``v_des`` (see ``clf.PointMassCLF``) in the body frame, which a
    velocity-controlled vehicle (MAVLink, simulator) tracks. ``escape`` enables the
    deadlock escape."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    model: Literal["unicycle", "double_integrator"] = "unicycle"
    """unicycle: planar LIMO-like robot (v, omega); double_integrator: 3-D point robot (body-frame velocity)."""
    platform: str | None = None
    """The robot's description (protocol/platforms.py PLATFORMS): its limits cap v_max, w_max and a_max; None: limo
    for the unicycle, point_mass for the double integrator."""
    k_rho: float = Field(0.8, gt=0)
    """unicycle: forward speed per metre of distance to the waypoint (1/s)."""
    k_alpha: float = Field(2.0, gt=0)
    """unicycle: yaw rate per radian of bearing error (1/s)."""
    k_p: float = Field(1.0, gt=0)
    """double_integrator: PD position gain."""
    k_d: float = Field(1.6, gt=0)
    """double_integrator: PD damping gain; the cruise speed is k_p / k_d per metre of error, capped at v_max."""
    v_max: float = Field(0.4, gt=0, le=10)
    """Largest commanded speed (m/s)."""
    w_max: float = Field(1.5, gt=0, le=20)
    """unicycle: largest commanded yaw rate (rad/s)."""
    a_max: float = Field(1.0, gt=0, le=50)
    """double_integrator: largest acceleration of the velocity demand (m/s^2)."""
    allow_reverse: bool = False
    """unicycle: drive backwards to a waypoint behind instead of turning round first."""
    state_timeout_s: float = Field(0.5, gt=0)
    """No state newer than this: the command is zero."""
    # Deadlock escape (see ``navigator.Navigator``): a CBF-filtered robot can stop for good in
    # front of an obstacle right on its path; then a side sub-goal is driven to for a while.
    escape: bool = True
    """Deadlock escape: after a stall, drive to a side sub-goal for escape_s, then resume."""
    stall_s: float = Field(4.0, gt=0)
    """A stall is stall_s without the distance to the target dropping by stall_progress."""
    stall_progress: float = Field(0.05, ge=0)
    """Progress (m) towards the target that must be made within stall_s."""
    escape_s: float = Field(4.0, gt=0)
    """How long the side sub-goal is driven to after a stall."""
    escape_angle_deg: float = Field(90.0, gt=0, lt=180)
    """Angle of the side sub-goal off the line to the target (degrees); the side alternates."""
    escape_distance: float = Field(0.8, gt=0)
    """Distance (m) of the side sub-goal from the robot."""

    @model_validator(mode="after")
    def _platform_fits_the_model(self) -> NavigatorConfig:
        p = self.robot_platform
        kind = PlanarPlatform if self.model == "unicycle" else SpatialPlatform
        if not isinstance(p, kind):
            what = "ground robot" if kind is PlanarPlatform else "point robot"
            raise ValueError(f"platform {p.name!r} is not a {what} for the {self.model} model")
        return self

    @property
    def robot_platform(self) -> PlanarPlatform | SpatialPlatform:
        return platform(self.platform or MODEL_PLATFORM[self.model])

    def unicycle(self) -> UnicycleCLF:
        v_max, w_max, p = self.v_max, self.w_max, self.robot_platform
        if isinstance(p, PlanarPlatform):
            v_max, w_max = min(v_max, p.max_linear), min(w_max, p.max_angular)
        return UnicycleCLF(self.k_rho, self.k_alpha, v_max, w_max, self.allow_reverse)

    def double_integrator(self) -> PointMassCLF:
        v_max, a_max, p = self.v_max, self.a_max, self.robot_platform
        if isinstance(p, SpatialPlatform):
            v_max = min(v_max, p.max_speed)
            a_max = a_max if p.max_accel is None else min(a_max, p.max_accel)
        return PointMassCLF(self.k_p, self.k_d, v_max, a_max)
