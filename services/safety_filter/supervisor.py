"""Fail-safe supervision around the filter: freshness and validity of the map, the state and
the reference, and the messages the node publishes.

The supervisor holds the newest map, state and reference with the local monotonic time each
arrived, and every input times out by its arrival. The map is also judged by its content:
``admit_map`` refuses a map that is stale, from the future, replayed or older than the one in
force, and ``tick(now, wall_ns)`` brakes with ``stale_map`` once the content in force is older
than the map timeout plus the clock-offset tolerance (``freshness.MapFreshness``), however
recently it arrived. ``tick`` returns the safe command and its status. It brakes, naming the
first problem found, in this order:

``no_map`` / ``invalid_map`` / ``stale_map`` → ``no_state`` / ``invalid_state`` / ``stale_state``
→ ``no_ref`` / ``invalid_ref`` / ``stale_ref`` → the filter's own ``outside_map``,
``non_finite``, ``infeasible``, ``solver_failed``.

"invalid" means the last message on that key could not be used; it holds until a valid one
arrives. Braking is the zero velocity command for every model.

Moving objects (``map/objects``, ``on_objects``) never brake: with ``object_motion`` on, the
newest ``TrackedObjects`` adds the objects' motion to the barrier (``motion``, ``model``) while it
is fresh — arrived within the map timeout and made from a map no more than the map timeout older
than the ESDF in force. Missing or stale, the step uses the static barrier; ``motion`` says which
(``off``, ``missing``, ``stale``, ``ok``) and ``counts`` counts the steps (``objects_missing``,
``objects_stale``).

Perception's alignment (``perception/alignment``, ``on_alignment``) never brakes either: once one
has arrived the field is read shrunk by the map scale's uncertainty, and while the estimate has not
converged the speed is capped (``scale_guard``); the status says so (``scale_uncertain``,
``distance_margin``, ``speed_cap``) and ``counts`` counts the steps (``scale_uncertain``).

An Ackermann chassis (``steering = "ackermann"``) drives a turn tighter than it can steer on its
tightest circle instead (``protocol.platforms.ackermann_steerable``), a path the filter did not
check. Such a command is replaced by the one the chassis will drive, if the filter passes that one
unchanged (its rows hold for it: the same barrier certifies it); otherwise the filter brakes
(``unsteerable``). The status says ``steering_limited`` on each replaced step.

``slack`` is the one fallback that does not brake: the QP was infeasible with fresh inputs and
the command is the slack-relaxed QP's, at least as safe as maximal braking along the field's
gradient (``filter``); the status says ``fallback="slack"`` on every such step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from riskfield.protocol import (
    Alignment,
    EsdfGrid,
    Header,
    RiskConfig,
    RobotState,
    SafetyStatus,
    TrackedObjects,
    VelocityCommand,
)
from riskfield.protocol.platforms import ackermann_steerable

from ..fields import DistanceField, EsdfField
from .evade import Evader, FreeFloor
from .filter import FilterResult, SafetyFilter
from .freshness import MapFreshness
from .motion import TrackEvidence, object_table
from .scale_guard import ScaleGuard, ScaleGuardConfig
from .state import FilterState

SOURCE = "safety-filter"
#: The brake when the command an Ackermann chassis would drive in place of the filtered one fails the barrier.
UNSTEERABLE = "unsteerable"


@dataclass
class _Slot:
    """The newest valid value of one input, when it arrived, and whether a bad message came since."""

    value: object | None = None
    at: float = -math.inf
    invalid: bool = False


class FilterSupervisor:
    """Tracks the inputs and turns them into (cmd/safe, safety/status) on every tick."""

    def __init__(self, filt: SafetyFilter, map_timeout_s: float = 0.3, state_timeout_s: float = 0.3,
                 ref_timeout_s: float = 0.2, clock_tolerance_s: float = 0.1,
                 scale_guard: ScaleGuardConfig | None = None):
        self.filter = filt
        #: the map's scale uncertainty (``perception/alignment``): a shrunk distance, a speed cap
        self.guard = ScaleGuard(scale_guard)
        self.freshness = MapFreshness(map_timeout_s, clock_tolerance_s, window_s=max(2.0, 5 * map_timeout_s))
        self._wall_ns: int | None = None  # the wall clock of the current tick, when the caller gives it
        self.timeouts = {"map": map_timeout_s, "state": state_timeout_s, "ref": ref_timeout_s}
        self._slots = {"map": _Slot(), "state": _Slot(), "ref": _Slot()}
        self.last: FilterResult | None = None
        self.counts: dict[str, int] = {}
        self._objects: tuple[TrackedObjects, float] | None = None
        self._evidence = TrackEvidence(filt.config.object_evidence)
        #: the opt-in retreat (``evade``), and the floor the newest map says was seen free
        self.evader = Evader(filt.model, filt.config, filt.delta)
        self._floor: FreeFloor | None = None
        self.motion = "off" if not filt.config.object_motion else "missing"

    # -- inputs ---------------------------------------------------------------------------------
    def on_map(self, grid: EsdfGrid | DistanceField, now: float) -> str | None:
        """Take a new map; returns why it was rejected (and marks the map invalid), or None."""
        try:
            field = (EsdfField.from_grid(grid, self.filter.config.interpolation) if isinstance(grid, EsdfGrid)
                     else grid)
        except ValueError as exc:
            self.invalid("map", now)
            return str(exc)
        self._set("map", field, now)
        self._floor = FreeFloor.from_grid(grid) if isinstance(grid, EsdfGrid) else None
        return None

    def admit_map(self, grid: EsdfGrid, now: float, wall_ns: int, publisher: str | None,
                  commit: bool = True) -> str | None:
        """Content and sequence checks before ``on_map``: None, or why the map is refused (the
        map in force is kept; a refused map never replaces a fresher one). ``commit=False``: the
        caller commits (``freshness.commit``) once ``on_map`` took the map."""
        return self.freshness.admit(grid.header.stamp_ns, grid.header.seq, publisher, now, wall_ns, commit)

    def on_state(self, msg: RobotState | FilterState, now: float) -> None:
        state = FilterState.from_message(msg) if isinstance(msg, RobotState) else msg
        if not state.is_finite():
            self.invalid("state", now)
            return
        self._set("state", state, now)

    def on_objects(self, msg: TrackedObjects | None, now: float) -> None:
        """The newest tracked objects (None: the last message was unusable; the static barrier)."""
        self._objects = None if msg is None else (msg, now)
        if msg is not None:
            self._evidence.observe(msg.objects, msg.header.stamp_ns)

    def objects(self, state: FilterState, now: float) -> np.ndarray | None:
        """The moving-object table for this step (predicted to the step's wall clock, or without one
        to the ESDF's stamp), or None for the static barrier; sets ``motion`` and counts a missing
        or stale input."""
        if not self.filter.config.object_motion:
            self.motion = "off"
            return None
        if self._objects is None:
            self.motion = "missing"
            self._count("objects_missing")
            return None
        msg, at = self._objects
        stamp = msg.header.stamp_ns
        esdf = self.freshness.stamp_ns if self.freshness.stamp_ns is not None else stamp
        limit = self.timeouts["map"]
        if now - at > limit or (esdf - stamp) * 1e-9 > limit:
            self.motion = "stale"
            self._count("objects_stale")
            return None
        self.motion = "ok"
        wall = self._wall_ns if self._wall_ns is not None else esdf
        return object_table(msg.objects, self.filter.config, wall, stamp, state.position, evidence=self._evidence)

    def on_ref(self, msg: VelocityCommand, now: float) -> None:
        self._set("ref", msg, now)

    def on_alignment(self, msg: Alignment, now: float) -> None:
        """Perception's newest SLAM → odometry estimate: how far the map's distances can be trusted."""
        self.guard.on_alignment(msg, now)

    @property
    def reference(self) -> VelocityCommand | None:
        """The newest valid reference taken (fresh or not), or None."""
        value = self._slots["ref"].value
        return value if isinstance(value, VelocityCommand) else None

    def invalid(self, what: str, now: float) -> None:
        """The newest message on ``what`` ("map", "state", "ref") was unusable: brake until a valid one."""
        self._slots[what].invalid = True

    def set_risk(self, risk: RiskConfig) -> None:
        self.filter.set_risk(risk)

    def _set(self, what: str, value: object, now: float) -> None:
        slot = self._slots[what]
        slot.value, slot.at, slot.invalid = value, now, False

    # -- output ---------------------------------------------------------------------------------
    def map_age_ms(self, now: float) -> float:
        slot = self._slots["map"]
        if slot.value is None:
            return -1.0
        content = None if self._wall_ns is None else self.freshness.age_s(self._wall_ns)
        # A content age below 0 is a clock offset within the tolerance; -1 stays "no map yet".
        return (now - slot.at) * 1e3 if content is None else max(content, 0.0) * 1e3

    def _problem(self, what: str, now: float) -> str | None:
        slot = self._slots[what]
        if slot.invalid:
            return f"invalid_{what}"
        if slot.value is None:
            return f"no_{what}"
        if now - slot.at > self.timeouts[what]:
            return f"stale_{what}"
        if what == "map" and self._wall_ns is not None and self.freshness.stale(self._wall_ns):
            return "stale_map"  # re-published, but made from data older than the timeout
        return None

    def tick(self, now: float, wall_ns: int | None = None) -> tuple[VelocityCommand, SafetyStatus]:
        """The safe command for ``now`` and the status explaining it. With ``wall_ns`` (the local
        wall clock) the map's content age is checked too and reported as ``esdf_age_ms``, and both
        messages are stamped with it: the stamp is the clock the step judged freshness by, so a
        receiver can check the content-age rule against the map stamps exactly."""
        self._wall_ns = wall_ns
        problem = self._problem("map", now) or self._problem("state", now) or self._problem("ref", now)
        field = self._slots["map"].value
        state = self._slots["state"].value
        ref = self._slots["ref"].value
        if problem is not None:
            h, rg = 0.0, 0
            if not problem.endswith("_map") and field is not None and isinstance(state, FilterState):
                h, rg, inside = self.filter.barrier(state, field)  # type: ignore[arg-type]
                if not inside or not math.isfinite(h):
                    h, rg = 0.0, 0
            return self._brake(problem, now, h, rg, wall_ns=wall_ns)
        assert isinstance(ref, VelocityCommand) and isinstance(state, FilterState)
        model = self.filter.model
        lin, ang = np.asarray(ref.linear, np.float64), np.asarray(ref.angular, np.float64)
        lin, ang, cap = self.guard.cap(lin, ang, now)
        u_ref = model.reference(lin, ang, state)
        field = self.guard.field(field)  # type: ignore[arg-type]
        objects = self.objects(state, now)
        res = self.filter.filter(state, u_ref, field, ang, objects)  # type: ignore[arg-type]
        self.last = res
        if res.fallback is not None and res.fallback != "slack":
            return self._brake(res.fallback, now, res.h, res.risk_group, res.solve_us, wall_ns)
        out_lin, out_ang = model.command(res.u, ang, state)
        if not (lin.any() or ang.any()):
            # A zero reference (the stick centred, the dead-man released) is a zero command: the
            # filter never moves the robot on its own, whatever comes at it.
            out_lin, out_ang = np.zeros(3), np.zeros(3)
        retreat = None
        if self.filter.config.evade and ref.engaged is not False:  # a released dead-man: nobody asked
            groups = getattr(self.filter.field_for(field), "groups", ())  # type: ignore[arg-type]
            retreat = self.evader.step(state, res.yielding, not (lin.any() or ang.any()), objects,
                                       self.filter.gains.for_groups(groups), field, self._floor)  # type: ignore[arg-type]
        if retreat is not None:
            out_lin, out_ang = model.command(retreat, np.zeros(3), state)
            self._count("evading")
        steered = False
        limit = self.filter.config.steering_limit
        if limit is not None:
            v, w = float(out_lin[0]), float(out_ang[2])
            _, w_driven = ackermann_steerable(v, w, *limit)
            if abs(w_driven - w) > 1e-9:
                out_ang = out_ang.copy()
                out_ang[2] = w_driven
                if not self._passes(state, out_lin, out_ang, field, objects):  # type: ignore[arg-type]
                    return self._brake(UNSTEERABLE, now, res.h, res.risk_group, res.solve_us, wall_ns)
                steered = True
                self._count("steering_limited")
        if not (np.isfinite(out_lin).all() and np.isfinite(out_ang).all()):
            return self._brake("non_finite", now, res.h, res.risk_group, res.solve_us, wall_ns)
        if cap is not None:  # the QP may trade speed for safety, never exceed the cap
            out_lin, out_ang, _ = self.guard.cap(out_lin, out_ang, now)
        self._count(res.fallback)
        cmd = VelocityCommand(header=_header(wall_ns), linear=tuple(out_lin.tolist()),
                              angular=tuple(out_ang.tolist()), source=f"{SOURCE}/{ref.source}")
        status = SafetyStatus(header=_header(wall_ns, "map"), h=res.h, risk_group=res.risk_group,
                              intervening=res.intervening, fallback=res.fallback,
                              solve_us=res.solve_us, esdf_age_ms=self.map_age_ms(now), yielding=res.yielding,
                              object_rows=res.object_rows, evading=retreat is not None,
                              scale_uncertain=self.guard.uncertain(now),
                              distance_margin=self.guard.margin_at(res.h + float(np.min(self.filter.model.radius))),
                              speed_cap=cap, steering_limited=steered)
        if status.scale_uncertain:
            self._count("scale_uncertain")
        if res.yielding:
            self._count("yielding")
        return cmd, status

    def _passes(self, state: FilterState, lin: np.ndarray, ang: np.ndarray, field: DistanceField,
                objects: np.ndarray | None) -> bool:
        """Whether the filter passes the body command (lin, ang) unchanged: every barrier row holds for it."""
        u = self.filter.model.reference(lin, ang, state)
        res = self.filter.filter(state, u, field, ang, objects)
        return res.fallback is None and not res.intervening

    def brake(self, reason: str, now: float) -> tuple[VelocityCommand, SafetyStatus]:
        """A brake decided outside ``tick`` (the node's shutdown, an error in the core), counted
        like the others."""
        return self._brake(reason, now, 0.0, 0)

    def _brake(self, reason: str, now: float, h: float, rg: int, solve_us: float = 0.0,
               wall_ns: int | None = None) -> tuple[VelocityCommand, SafetyStatus]:
        self._count(reason)
        cmd = VelocityCommand.zero(SOURCE, header=_header(wall_ns))
        status = SafetyStatus(header=_header(wall_ns, "map"), h=h if math.isfinite(h) else 0.0,
                              risk_group=max(int(rg), 0), intervening=True,
                              fallback=reason, solve_us=solve_us if math.isfinite(solve_us) else 0.0,
                              esdf_age_ms=self.map_age_ms(now))
        return cmd, status

    def _count(self, reason: str | None) -> None:
        key = reason or "ok"
        self.counts[key] = self.counts.get(key, 0) + 1


def _header(wall_ns: int | None, frame_id: str = "base_link") -> Header:
    """A step's messages are stamped with the step's wall clock, when it has one."""
    return Header(frame_id=frame_id) if wall_ns is None else Header(frame_id=frame_id, stamp_ns=wall_ns)
