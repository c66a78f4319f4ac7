"""The safety filter: a CBF-QP on the semantic ESDF that keeps a robot clear of obstacles, with
risk-group dependent gains ("CBF Formulation with Semantics", "Optimization-Based Safety
Filter" and the look-ahead teleoperation formulation of the paper).

Pure core (no I/O, no zenoh), usable directly by a simulation::

    from riskfield.services.safety_filter import EsdfField, FilterConfig, FilterState, SafetyFilter

    filt = SafetyFilter(FilterConfig(model="double3d"))        # or unicycle, single2d, single3d
    field = EsdfField.from_grid(esdf_grid)                     # or an analytic field (analytic.py)
    res = filt.filter(FilterState(p, R, v), u_nominal, field)  # res.u, res.h, res.fallback, ...
    state = filt.model.integrate(state, res.u, filt.config.dt)  # exact dynamics, zero-order hold

Modules, one concept each: ``field`` (ESDF access: trilinear distance, finite-difference
gradient and Hessian, risk group; the filter reads it with the cubic B-spline of
``services/field_spline.py`` by default), ``analytic`` (closed-form fields), ``state`` (robot state,
rotations), ``barriers`` (dynamics, h, CBF rows per model), ``qp`` (exact active-set path and
OSQP), ``filter`` (one filter step, gains per risk group), ``config`` (the core's settings),
``supervisor`` (timeouts and fail-safe reasons → messages). Node side: ``settings``,
``risk_file``, ``node``; ``bench`` is ``riskfield bench filter``.
"""

from ..esdf_field import DistanceField, EsdfField, FieldSample
from .analytic import Box, Plane, Sphere, Union, to_esdf, to_grid_message
from .barriers import BarrierModel, DoubleIntegrator, SingleIntegrator, UnicycleLookahead
from .config import FilterConfig, Footprint
from .filter import FilterResult, GainTable, SafetyFilter
from .qp import ActiveSetSolver, OsqpSolver, QPResult
from .state import FilterState
from .supervisor import FilterSupervisor

__all__ = [
    "ActiveSetSolver",
    "BarrierModel",
    "Box",
    "DistanceField",
    "DoubleIntegrator",
    "EsdfField",
    "FieldSample",
    "FilterConfig",
    "FilterResult",
    "FilterState",
    "FilterSupervisor",
    "Footprint",
    "GainTable",
    "OsqpSolver",
    "Plane",
    "QPResult",
    "SafetyFilter",
    "SingleIntegrator",
    "Sphere",
    "UnicycleLookahead",
    "Union",
    "to_esdf",
    "to_grid_message",
]
