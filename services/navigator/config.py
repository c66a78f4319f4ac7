"""Configuration of the navigator: which robot model, CLF gains and limits, timing."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from .clf import DoubleIntegratorCLF, UnicycleCLF


class NavigatorConfig(BaseModel):
    """``model = "unicycle"``: planar LIMO-like robot, command ``(v, 0, 0) / (0, 0, ω)``.
    ``model = "double_integrator"``: 3-D point robot; the command is the CLF's velocity
    demand ``v_des`` (see ``clf.DoubleIntegratorCLF``) in the body frame, which a
    velocity-controlled vehicle (MAVLink, simulator) tracks. ``escape`` enables the
    deadlock escape."""

    model_config = ConfigDict(extra="forbid")

    model: Literal["unicycle", "double_integrator"] = "unicycle"
    k_rho: float = Field(0.8, gt=0)
    k_alpha: float = Field(2.0, gt=0)
    k_p: float = Field(1.0, gt=0)
    k_d: float = Field(1.6, gt=0)
    v_max: float = Field(0.4, gt=0, le=10)
    w_max: float = Field(1.5, gt=0, le=20)
    a_max: float = Field(1.0, gt=0, le=50)
    allow_reverse: bool = False
    state_timeout_s: float = Field(0.5, gt=0)
    # Deadlock escape (see ``navigator.Navigator``): a CBF-filtered robot can stop for good in
    # front of an obstacle right on its path; then a side sub-goal is driven to for a while.
    escape: bool = True
    stall_s: float = Field(4.0, gt=0)
    stall_progress: float = Field(0.05, ge=0)
    escape_s: float = Field(4.0, gt=0)
    escape_angle_deg: float = Field(90.0, gt=0, lt=180)
    escape_distance: float = Field(0.8, gt=0)

    def unicycle(self) -> UnicycleCLF:
        return UnicycleCLF(self.k_rho, self.k_alpha, self.v_max, self.w_max, self.allow_reverse)

    def double_integrator(self) -> DoubleIntegratorCLF:
        return DoubleIntegratorCLF(self.k_p, self.k_d, self.v_max, self.a_max)
