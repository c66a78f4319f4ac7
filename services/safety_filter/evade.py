"""Evasion, on request only: retreat from someone who keeps coming, and only into floor seen free.

Yielding (``model``) stops the robot for a moving object; when the object comes on at the stopped
robot, stopping is not enough and the robot stays stopped. With ``evade`` on, the supervisor asks
:class:`Evader` for a retreat instead. There is one only when all of these hold:

* an object is on a collision course with the robot at rest (``model.object_course`` with the body
  stopped: the same test the rows use), so someone walking past never starts one;
* a retreat at ``evade_speed`` along one of the model's translating inputs (a unicycle: back or
  forth) puts off the contact with the object (its reach grown by σ t, as in the course, without
  the margin), or avoids it within the collision horizon, where staying put would not;
* the footprint that retreat sweeps in ``evade_lookahead_s`` lies in floor the mapper observed free
  within its ``observed_free_s`` (``EsdfGrid.observed_free``: unknown is not free, so a wall behind
  the robot that the front camera never saw stops it), and no body disc comes nearer an inflated
  obstacle of the ESDF than it is now or than its radius (a disc already inside the margin of the
  person it backs away from may only gain);
* the robot has retreated less than ``evade_distance`` since the threat began.

Of the retreats that qualify, the one with the latest contact wins. A retreat is
for velocity-controlled models (order 1); the double integrator never evades.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import EsdfGrid

from ..fields import DistanceField
from . import model as mdl
from .barriers import BarrierModel
from .config import MotionParams
from .state import FilterState

#: samples of the swept footprint over the look-ahead, and around each body disc's rim
SWEEP_SAMPLES = 8
RIM_SAMPLES = 8
#: samples of the collision horizon when a retreat's contact is timed
CONTACT_SAMPLES = 60


@dataclass(frozen=True)
class FreeFloor:
    """The floor the mapper observed free (``EsdfGrid.observed_free``), as a 2-D lookup."""

    origin: np.ndarray  # (2,) centre of cell (0, 0)
    voxel_size: float
    free: np.ndarray  # (nx, ny) bool

    @classmethod
    def from_grid(cls, grid: EsdfGrid) -> FreeFloor | None:
        if grid.observed_free is None:
            return None
        return cls(np.asarray(grid.origin[:2], np.float64), float(grid.voxel_size),
                   np.asarray(grid.observed_free).any(axis=2))

    def covers(self, xy: np.ndarray) -> bool:
        """Every point (k, 2) lies in a cell observed free (outside the grid: not)."""
        ij = np.floor((np.asarray(xy, np.float64) - self.origin) / self.voxel_size + 0.5).astype(np.int64)
        nx, ny = self.free.shape
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        if not inside.all():
            return False
        return bool(self.free[ij[:, 0], ij[:, 1]].all())


class Evader:
    """The retreat (module doc) for one filter model; holds how far the current retreat has gone."""

    def __init__(self, model: BarrierModel, params: MotionParams, delta: float):
        self.model, self.params, self.delta = model, params, delta
        self.retreated = 0.0
        self._last_xy: np.ndarray | None = None
        self.candidates = self._candidates() if model.spec.order == 1 else np.zeros((0, model.n))
        angles = np.linspace(0.0, 2 * math.pi, RIM_SAMPLES, endpoint=False)
        self._rim = np.column_stack([np.cos(angles), np.sin(angles)])

    def _candidates(self) -> np.ndarray:
        """±evade_speed on each input that translates the body (``ModelSpec.lin``'s non-zero columns)."""
        lin, speed = self.model.spec.lin, self.params.evade_speed
        out = []
        for j in range(self.model.n):
            if np.any(lin[:, j] != 0.0):
                for sign in (1.0, -1.0):
                    u = np.zeros(self.model.n)
                    u[j] = sign * min(speed, float(self.model.hi[j]), float(-self.model.lo[j]))
                    out.append(u)
        return np.array(out).reshape(-1, self.model.n)

    def reset(self) -> None:
        self.retreated, self._last_xy = 0.0, None

    def step(self, state: FilterState, yielding: bool, idle: bool, objects: np.ndarray | None, gains: np.ndarray,
             field: DistanceField, floor: FreeFloor | None) -> np.ndarray | None:
        """The retreat for a step in which the filter yielded or the reference asked to stand, else
        None; a step that drives on ends the retreat, so the next threat starts a new one."""
        if not (yielding or idle):
            self.reset()
            return None
        return self.command(state, objects, gains, field, floor)

    def command(self, state: FilterState, objects: np.ndarray | None, gains: np.ndarray, field: DistanceField,
                floor: FreeFloor | None) -> np.ndarray | None:
        """The retreat input for this step, or None (stay as the filter decided). ``gains``: the gain
        table of the field's groups (``SafetyFilter.gains.for_groups``), for each object's margin."""
        if not self.params.evade or objects is None or not len(objects) or not len(self.candidates):
            self.reset()
            return None
        m = self.model
        pts = m.points(state)
        rest = np.zeros(3)
        threat = [obj for obj in objects if math.isfinite(self._course(pts, rest, obj, gains))]
        if not threat:
            self.reset()
            return None
        xy = np.asarray(state.position[:2], np.float64)
        if self._last_xy is not None:
            self.retreated += float(np.hypot(*(xy - self._last_xy)))
        self._last_xy = xy
        if floor is None or self.retreated >= self.params.evade_distance:
            return None
        rot = m.rotation(state)
        best, best_t = None, min(self._contact(pts, rest, obj) for obj in threat)
        for u in self.candidates:
            v = np.empty(3)
            mdl.reference_velocity(m.di, m.df, m.dl, rot, np.zeros(3), u, v)
            t = min(self._contact(pts, v, obj) for obj in threat)
            if t <= best_t or not self._clear(pts, v, field, floor):
                continue
            best, best_t = u, t
        return None if best is None else best.copy()

    def _contact(self, pts: np.ndarray, v: np.ndarray, obj: np.ndarray) -> float:
        """When (s) the object, its reach grown by σ t, first touches the body moving on at ``v``,
        on a finer grid than the course's (a retreat buys tenths of a second), or inf."""
        obj = np.ascontiguousarray(obj, np.float64)
        for t in np.linspace(0.0, self.params.collision_horizon_s, CONTACT_SAMPLES + 1):
            if mdl.object_gap(self.model.df, self.model.dl, pts, v[0] * t, v[1] * t, obj, t) <= obj[mdl.OBJ_SIGMA] * t:
                return float(t)
        return math.inf

    def _course(self, pts: np.ndarray, v: np.ndarray, obj: np.ndarray, gains: np.ndarray) -> float:
        """When the object comes inside its group's margin of the body moving on at ``v``, or inf."""
        margin = float(gains[min(int(obj[mdl.OBJ_GROUP]), gains.shape[0] - 1)][mdl.MARGIN])
        # Both of object_course's futures are the body moving on at v, as the retreat would: its
        # braking future with a vanishing deceleration never slows within the horizon.
        return mdl.object_course(self.model.desc, pts, v, v, np.ascontiguousarray(obj, np.float64),
                                 margin, self.delta, self.params.collision_horizon_s, 1e-12)

    def _clear(self, pts: np.ndarray, v: np.ndarray, field: DistanceField, floor: FreeFloor) -> bool:
        """The footprint swept at ``v`` over the look-ahead: in observed-free floor, out of obstacles."""
        t = np.linspace(0.0, self.params.evade_lookahead_s, SWEEP_SAMPLES + 1)
        swept = pts[None, :, :] + t[:, None, None] * v[None, None, :]  # (samples, m, 3)
        flat = swept.reshape(-1, 3)
        sample = field.query(flat)
        if not sample.inside.all():
            return False
        clearance = (sample.distance.reshape(len(t), -1) - self.model.radius[None, :])
        if np.any(clearance < np.minimum(clearance[0], 0.0)[None, :] - 1e-9):
            return False
        radii = np.tile(self.model.radius, len(t))
        rim = flat[:, None, :2] + radii[:, None, None] * self._rim[None, :, :]
        return floor.covers(np.concatenate([flat[:, :2], rim.reshape(-1, 2)]))
