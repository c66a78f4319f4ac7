"""The safety filter: a CBF-QP on the semantic ESDF that keeps a robot clear of obstacles, with
risk-group dependent gains ("CBF Formulation with Semantics", "Optimization-Based Safety
Filter" and the look-ahead teleoperation formulation of the paper).

Pure core (no I/O, no zenoh), usable directly by a simulation::

    from riskfield.services.fields import EsdfField
    from riskfield.services.safety_filter import FilterConfig, FilterState, SafetyFilter

    filt = SafetyFilter(FilterConfig(model="double3d"))        # or unicycle, single2d, single3d
    field = EsdfField.from_grid(esdf_grid)                     # or any riskfield.services.fields field
    res = filt.filter(FilterState(p, R, v), u_nominal, field)  # res.u, res.h, res.fallback, ...
    state = filt.model.integrate(state, res.u, filt.config.dt)  # exact dynamics, zero-order hold

The field it reads (ESDF grid, analytic or point-cloud) is ``riskfield.services.fields``; the
filter reads an ESDF grid with the smoothing cubic B-spline of ``fields.spline`` by default.
Modules, one concept each: ``state`` (robot state), ``barriers`` (dynamics, h, CBF rows per
model, footprint disc cover), ``filter`` (one filter step, gains per risk group, slack-relaxed
fallback), ``compiled`` (the step itself: field query, rows and the exact QP as numba kernels),
``config`` (the core's settings),
``supervisor`` (timeouts and fail-safe reasons → messages). Node side: ``settings``,
``node`` (the runtime holds the risk file); the bench is ``riskfield bench filter``.
"""

from .barriers import BarrierModel, DoubleIntegrator, SingleIntegrator, UnicycleLookahead
from .config import FilterConfig, Footprint
from .filter import FilterResult, GainTable, SafetyFilter
from .state import FilterState
from .supervisor import FilterSupervisor

__all__ = [
    "BarrierModel",
    "DoubleIntegrator",
    "FilterConfig",
    "FilterResult",
    "FilterState",
    "FilterSupervisor",
    "Footprint",
    "GainTable",
    "SafetyFilter",
    "SingleIntegrator",
    "UnicycleLookahead",
]
