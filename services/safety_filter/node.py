"""The ``safety-filter`` node: ESDF + state + reference in, ``cmd/safe`` + ``safety/status`` out.

Subscribes ``{robot}/map/esdf``, ``{robot}/state`` and ``{robot}/cmd/ref`` (latest-value queues),
``{robot}/config/risk`` and ``{robot}/map/objects`` (tracked people and animals: their motion
enters the barrier, ``supervisor``; missing, stale or invalid it is the static barrier, counted in
``objects_missing``, ``objects_stale``, ``invalid_objects``, never a brake) and ``{robot}/perception/alignment``
(the map scale's uncertainty: a shrunk distance and a speed cap, ``scale_guard``); publishes on every
new reference, on every map taken (accepted or unusable; ``step_on_map``) and at ``rate_hz`` (a
tick is skipped when such a step went out less than half a period before). The map, state and
reference are decoded here rather than by the runtime so that a bad message is not only counted
and logged but also makes the filter brake (``invalid_*``) until a good one arrives. The risk
configuration hot-reloads from the config key and from ``risk_file`` (polled every
``risk_poll_s``, see ``runtime.risk_file``); a bad configuration is logged, counted
(``risk_errors``) and the old one kept.

The map is judged by its content (``freshness``): a map whose stamp is already too old or in the
future, whose publisher's ``seq`` went backwards, or that is older than the map in force is
refused, counted (``map_refused``, ``map_refused_<reason>``) and logged, and the map in force is
kept; ``SafetyStatus.esdf_age_ms`` is the content age, ``esdf_publishers`` the number of
publishers on ``map/esdf`` lately (2 or more is a fault: a stuck or rogue mapper).

Several sources may publish ``cmd/ref``; the node takes a reference only from the one the
arbitration names (``runtime.arbiter``, twist_mux's rules): the highest-priority source (by
``VelocityCommand.source``, ``ref_sources``; the joystick outranks the navigator) that sent a
claiming command within its timeout. Others are counted (``ref_refused``, ``ref_refused_<reason>``).
A joystick whose dead-man is released sends ``engaged = False``: it keeps control until its claim
times out, then the navigator's next command is taken. ``{robot}/cmd/lock`` (additive key,
``CommandLock``) holds every source below ``lock_priority``: while the reference in force comes from
a held source the filter brakes with ``fallback = "locked"``. ``SafetyStatus.ref_source`` names the
source listened to. The arbitration decides which reference enters the step, never the step itself.
Each source puts on its own key, ``cmd/ref/<source>`` and ``cmd/lock/<source>`` (additive): a
message whose key names another source than it declares is refused (``ref_refused_source_mismatch``,
``lock_refused_source_mismatch``), so on a secure site, whose routers let only a source's identity
put its key, no identity can take another's priority or release its lock. The plain keys trust the
declared source and are taken unless ``ref_plain_key`` is false (``..._plain_key``).

The risk configuration in force has a version and a hash (``runtime.risk_file.RiskStore``), in
``SafetyStatus.risk_version`` / ``risk_hash`` and ``NodeStatus``; with ``state_dir`` it is kept
there and reloaded at the next start (the risk file, when set, is loaded over it). One that names
no obstacle does not decode (``RiskConfig``'s floor): counted in ``NodeStatus.invalid`` and logged.

A state that jumps farther than the robot can move since the last one taken, or is stamped ahead
of this clock, is refused (``runtime.continuity``; ``state_refused``, ``state_refused_<reason>``):
the state in force is kept and times out into ``stale_state`` if no consistent one follows. An
announced jump on ``{robot}/state/relocalise`` (additive key) is taken as the new state.

The last word is a brake: on every shutdown the process can act on (SIGINT, SIGTERM, an exception
that ends the loop) a close hook publishes a zero ``cmd/safe`` with ``fallback="shutdown"`` while
the session is still open, and a step that raises publishes a zero command with
``fallback="internal_error"`` before the error is logged. After a SIGKILL nothing can be sent:
the bridges' watchdogs stop the platform.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from riskfield.protocol import (
    Alignment,
    CommandLock,
    DecodeError,
    EsdfGrid,
    Limits,
    RiskConfig,
    RobotState,
    TrackedObjects,
    VelocityCommand,
    decode,
)
from riskfield.protocol.keys import source_of

from ..runtime.arbiter import LOCKED, PLAIN_KEY, SOURCE_MISMATCH
from ..runtime.continuity import StateGate, report_refused
from ..runtime.node import Node
from ..runtime.risk_file import RiskStore, watch_risk_file
from ..runtime.service import ServiceSpec
from .filter import SafetyFilter
from .settings import FilterSettings
from .supervisor import FilterSupervisor

#: References the plain cmd/ref key queues: a few per source of a deployment's usual two or three.
PLAIN_REF_BACKLOG = 8


class FilterNode:
    """Glue between the runtime node and the supervisor (decode → core → encode → publish)."""

    def __init__(self, node: Node, s: FilterSettings):
        self.node = node
        self.settings = s
        # The configuration in force, its version and digest, kept under state_dir (module doc).
        self.risk_store = RiskStore(s.state_dir, node.service, node.log)
        # A bad file at start is a configuration error; later ones keep the configuration in force.
        if s.risk_file:
            self.risk_store.commit(watch_risk_file(node, s.risk_file, s.risk_poll_s, self._set_risk),
                                   str(s.risk_file))
        risk = self.risk_store.risk
        self._show_risk()
        self.supervisor = FilterSupervisor(SafetyFilter(s.filter_config(), risk, warm_up=False), s.map_timeout_s,
                                           s.state_timeout_s, s.ref_timeout_s, s.clock_tolerance_s,
                                           s.scale_guard())
        self.period = 1.0 / s.rate_hz
        self._last_pub = -1e9
        self._last_fallback: str | None = "start"
        # distance (4 B/voxel) and risk_group (1 B/voxel) travel together: the payload is ~1.25 × distance
        self._map_limits = Limits(max_payload_bytes=2 * s.max_map_bytes + 65536, max_array_bytes=s.max_map_bytes)
        self._small_limits = Limits(max_payload_bytes=64 * 1024, max_array_bytes=4096)
        self._objects_limits = Limits(max_payload_bytes=1024 * 1024, max_array_bytes=4096)
        self._last_motion = self.supervisor.motion
        for name in ("steps", "brakes", "slack", "intervening", "invalid_map", "invalid_state", "invalid_ref",
                     "risk_reloads", "risk_errors", "map_refused", "esdf_publishers", "invalid_objects",
                     "objects_missing", "objects_stale", "objects_moving", "state_refused", "yielding", "object_rows",
                     "ref_refused", "locks", "invalid_lock"):
            node.stats[name] = 0.0
        self.mux = s.command_mux()  # cmd/ref arbitration (module doc)
        self.state_gate = StateGate.of(s, s.clock_tolerance_s)  # continuity of the state (module doc)
        k = node.keys
        node.subscribe(k.esdf, None, self._on_map, queue="latest")
        node.subscribe(k.state, None, self._on_state, queue="latest")
        node.subscribe(k.state_relocalise, None, self._on_relocalise, queue="fifo", maxlen=4)
        # Each source's key keeps its own newest reference (a wildcard latest subscription has a slot
        # per key); the plain key, which several sources may share, keeps the last few in order, so
        # on a busy machine one source's newest does not displace another's before the arbitration
        # has seen it (a navigator's lost claims would time its input out, a joystick's would hand
        # the robot to the navigator while the dead-man is held).
        node.subscribe(k.cmd_ref, None, self._on_ref, queue="fifo", maxlen=PLAIN_REF_BACKLOG)
        node.subscribe(k.key("cmd/ref/*/**"), None, self._on_ref, queue="latest")
        node.subscribe(k.cmd_lock_any, None, self._on_lock, queue="fifo", maxlen=64)
        node.subscribe(k.risk_config, RiskConfig, self._on_risk, queue="latest")
        node.subscribe(k.objects, None, self._on_objects, queue="latest")
        node.subscribe(k.alignment, Alignment, self._on_alignment, queue="latest")
        node.every(self.period, self._on_timer)
        # The compiled step is loaded (or compiled) here, in setup, never on a control step; after
        # subscribing, so that what arrives meanwhile waits in the inbox for the loop.
        t0 = time.perf_counter()
        self.supervisor.filter.warm_up()
        node.log.info("safety filter: step ready in %.2f s", time.perf_counter() - t0)
        node.on_close(self._brake_on_close)
        model = self.supervisor.filter.model
        node.log.info("safety filter: model %s, %d barrier row(s), δ = %.3f m, %.0f Hz", model.name, model.m,
                      self.supervisor.filter.delta, s.rate_hz)

    # -- inputs -----------------------------------------------------------------------------------
    def _decode(self, what: str, payload: bytes, msg_type: type, limits: Limits) -> Any:
        try:
            return decode(payload, msg_type, limits)
        except DecodeError as exc:
            self.supervisor.invalid(what, time.monotonic())
            self.node.stats[f"invalid_{what}"] += 1
            self.node.ratelog(logging.WARNING, f"invalid_{what}", f"rejected a {what} message ({exc}): braking")
            return None

    def _on_map(self, key: str, payload: bytes) -> None:
        grid = self._decode("map", payload, EsdfGrid, self._map_limits)
        if grid is None:
            return
        now = time.monotonic()
        refused = self.supervisor.admit_map(grid, now, time.time_ns(), self.node.source_id, commit=False)
        if refused is not None:
            st = self.node.stats
            st["map_refused"] += 1
            st[f"map_refused_{refused}"] = st.get(f"map_refused_{refused}", 0) + 1
            self.node.ratelog(logging.WARNING, f"map_refused:{refused}",
                              f"refused an ESDF ({refused}: stamp {grid.header.stamp_ns}, seq {grid.header.seq}, "
                              f"publisher {self.node.source_id}); keeping the map in force")
            return
        reason = self.supervisor.on_map(grid, now)
        if reason is not None:
            self.node.stats["invalid_map"] += 1
            self.node.ratelog(logging.WARNING, "invalid_map", f"unusable ESDF ({reason}): braking")
        else:  # only a map taken moves its publisher's seq and the content stamp (freshness)
            self.supervisor.freshness.commit(grid.header.stamp_ns, grid.header.seq, self.node.source_id)
        # A new map acts at once, not at the next tick (up to a period later): an obstacle just
        # seen bounds the command now, and camera → cmd/safe loses the filter's sampling delay.
        if self.settings.step_on_map:
            self._step()

    def _on_state(self, key: str, payload: bytes, relocalise: bool = False) -> None:
        msg = self._decode("state", payload, RobotState, self._small_limits)
        if msg is None:
            return
        now = time.monotonic()
        gate = self.state_gate.relocalise if relocalise else self.state_gate.admit
        refused = gate(msg.position, msg.header.stamp_ns, now, time.time_ns())
        if refused is not None:
            report_refused(self.node, self.state_gate, refused, msg.position, msg.header.stamp_ns,
                           "keeping the state in force")
            return
        self.supervisor.on_state(msg, now)

    def _on_relocalise(self, key: str, payload: bytes) -> None:
        self._on_state(key, payload, relocalise=True)

    def _misnamed(self, key: str, declared: str) -> str | None:
        """Why a cmd/ref or cmd/lock message on ``key`` is not taken as from ``declared``, or None:
        ``cmd/<x>/<source>`` must name the source the message declares (the routers let only
        that source's identity put the key, protocol.keys.REF_SOURCES); the plain key is taken
        only with ``ref_plain_key``."""
        named = source_of(self.node.keys.relative(key) or "")
        if named is None:
            return None if self.settings.ref_plain_key else PLAIN_KEY
        return None if named == declared else SOURCE_MISMATCH

    def _refuse_ref(self, refused: str, key: str, source: str, now: float) -> None:
        st = self.node.stats
        st["ref_refused"] += 1
        st[f"ref_refused_{refused}"] = st.get(f"ref_refused_{refused}", 0) + 1
        if refused != "preempted":  # giving way is the normal case; the others are worth a line
            self.node.ratelog(logging.WARNING, f"ref_refused:{refused}",
                              f"not taking {key} from {source!r} ({refused}; listening to "
                              f"{self.mux.active(now)!r})")

    def _on_ref(self, key: str, payload: bytes) -> None:
        msg = self._decode("ref", payload, VelocityCommand, self._small_limits)
        if msg is not None:
            now = time.monotonic()
            refused = self._misnamed(key, msg.source)
            if refused is None:
                refused = self.mux.admit(msg.source, now, claims=msg.engaged is not False)
            if refused is not None:
                self._refuse_ref(refused, key, msg.source, now)
                return
            self.supervisor.on_ref(msg, now)
        self._step()  # a bad reference brakes at once, too

    def _on_lock(self, key: str, payload: bytes) -> None:
        try:
            lock = decode(payload, CommandLock, self._small_limits)
        except DecodeError as exc:  # not a brake: a lock that does not decode changes nothing
            self.node.stats["invalid_lock"] += 1
            self.node.ratelog(logging.WARNING, "invalid_lock", f"rejected a cmd/lock message ({exc})")
            return
        now = time.monotonic()
        refused = self._misnamed(key, lock.source)
        if refused is not None:
            self.node.stats[f"lock_refused_{refused}"] = self.node.stats.get(f"lock_refused_{refused}", 0) + 1
            self.node.ratelog(logging.WARNING, f"lock_refused:{refused}",
                              f"not taking the lock on {key} from {lock.source!r} ({refused})")
            return
        was = self.mux.lock_priority(now)
        self.mux.lock(lock.source, lock.locked, now)
        self.node.stats["locks"] += lock.locked
        if self.mux.lock_priority(now) != was:
            self.node.log.warning("cmd/ref lock %s by %r: sources below priority %d held", "on" if lock.locked
                                  else "off", lock.source, self.mux.lock_priority(now))
        self._step()  # a lock brakes now, not at the next tick

    def _on_objects(self, key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, TrackedObjects, self._objects_limits)
        except DecodeError as exc:
            # Not a brake: without usable objects the barrier is the static one (supervisor).
            self.supervisor.on_objects(None, time.monotonic())
            self.node.stats["invalid_objects"] += 1
            self.node.ratelog(logging.WARNING, "invalid_objects",
                              f"rejected a map/objects message ({exc}): static barrier until a good one")
            return
        self.supervisor.on_objects(msg, time.monotonic())

    def _on_alignment(self, msg: Alignment) -> None:
        # Not a brake when bad or missing: the runtime drops and counts an invalid one, and the last
        # good one times out into "not converged" (speed cap) while the map it scaled goes stale.
        self.supervisor.on_alignment(msg, time.monotonic())
        self.node.stats["align_sigma"] = msg.scale_sigma

    def _on_risk(self, risk: RiskConfig) -> None:
        # A configuration naming no obstacle never gets here: it does not decode (RiskConfig's
        # floor), counted in NodeStatus.invalid and logged by the runtime.
        self.supervisor.set_risk(risk)
        self.node.stats["risk_reloads"] += 1
        self.risk_store.commit(risk, self.node.keys.risk_config)
        self._show_risk()

    def _set_risk(self, risk: RiskConfig) -> None:
        self.supervisor.set_risk(risk)
        self.risk_store.commit(risk, str(self.settings.risk_file))
        self._show_risk()

    def _show_risk(self) -> None:
        self.node.status_fields.update(risk_version=self.risk_store.version, risk_hash=self.risk_store.digest)
        self.node.stats["risk_version"] = self.risk_store.version

    # -- output -----------------------------------------------------------------------------------
    def _on_timer(self) -> None:
        if time.monotonic() - self._last_pub >= 0.5 * self.period:
            self._step()

    def _brake(self, reason: str) -> None:
        """Publish a zero command and a status saying ``reason``, outside the supervisor's tick."""
        cmd, status = self.supervisor.brake(reason, time.monotonic())
        status.risk_version, status.risk_hash = self.risk_store.version, self.risk_store.digest
        self.node.publish(self.node.keys.cmd_safe, cmd)
        self.node.publish(self.node.keys.safety_status, status)
        self._last_pub = time.monotonic()

    def _brake_on_close(self) -> None:
        # The session is still open here (Node.close runs hooks first): without this, the last
        # cmd/safe of a stopped filter is whatever it last sent, possibly a moving command.
        self._brake("shutdown")
        self.node.log.info("safety filter stopping: sent a brake on %s", self.node.keys.cmd_safe)

    def _step(self) -> None:
        now = time.monotonic()
        try:
            ref = self.supervisor.reference
            if ref is not None and self.mux.masked(ref.source, now):
                cmd, status = self.supervisor.brake(LOCKED, now)  # the reference in force is held by a lock
            else:
                cmd, status = self.supervisor.tick(now, time.time_ns())
        except Exception:
            # A bug in the core must not leave the last moving command in force; the runtime
            # logs and counts the error (Node._call) and the next step tries again.
            self._brake("internal_error")
            raise
        status.risk_errors = int(self.node.stats.get("risk_errors", 0))
        status.ref_source = self.mux.active(now)
        status.risk_version, status.risk_hash = self.risk_store.version, self.risk_store.digest
        fresh = self.supervisor.freshness
        status.esdf_publishers = fresh.publishers(now)
        status.esdf_refused = fresh.refused_total
        if status.esdf_publishers > 1:
            self.node.ratelog(logging.WARNING, "esdf_publishers",
                              f"{status.esdf_publishers} publishers on {self.node.keys.esdf}: a stuck or rogue mapper")
        self.node.publish(self.node.keys.cmd_safe, cmd)
        self.node.publish(self.node.keys.safety_status, status)
        self._last_pub = now
        st = self.node.stats
        st["steps"] += 1
        st["object_rows"] = status.object_rows
        st["yielding"] += status.yielding
        st["brakes"] += status.fallback is not None and status.fallback != "slack"
        st["slack"] += status.fallback == "slack"
        st["intervening"] += status.intervening and status.fallback is None
        st["solve_us"] = status.solve_us
        st["h"] = status.h
        st["esdf_publishers"] = status.esdf_publishers
        st["scale_uncertain"] = st.get("scale_uncertain", 0) + status.scale_uncertain
        motion = self.supervisor.motion
        if motion in ("missing", "stale", "ok"):
            st["objects_" + ("moving" if motion == "ok" else motion)] += 1
        if motion != self._last_motion:
            if motion in ("missing", "stale") and self._last_motion == "ok":
                self.node.ratelog(logging.WARNING, f"objects_{motion}",
                                  f"{self.node.keys.objects} {motion}: the static barrier (moving objects not seen)")
            elif motion == "ok":
                self.node.log.info("moving objects from %s in the barrier", self.node.keys.objects)
            self._last_motion = motion
        if status.fallback != self._last_fallback:
            if status.fallback is None:
                self.node.log.info("filtering (no fallback)")
            else:
                what = "slack-relaxed QP (infeasible)" if status.fallback == "slack" else "braking"
                self.node.ratelog(logging.WARNING, f"fallback:{status.fallback}", f"{what}: {status.fallback}")
            self._last_fallback = status.fallback


def setup(node: Node, settings: FilterSettings) -> FilterNode:
    return FilterNode(node, settings)


SERVICE = ServiceSpec("safety-filter", FilterSettings, setup)
