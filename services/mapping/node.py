"""The mapping node: the thin Zenoh wrapper around ``Mapper``.

Subscribes
    ``{prefix}/{robot}/perception/frame``  PerceptionFrame, latest value → ``Mapper.integrate``
    ``{prefix}/{robot}/state``             RobotState, latest value → the volume follows the robot; a
                                           sample that jumps farther than the robot can move is refused
                                           (``runtime.continuity``; ``state_refused``, ``state_refused_<reason>``)
    ``{prefix}/{robot}/state/relocalise``  RobotState: an announced jump (additive key), taken as it is
    ``{prefix}/{robot}/config/risk``       RiskConfig → margins and obstacle labels of the next ESDF
Publishes, at most ``esdf_rate_hz`` and only after new data (frame, recentring, risk config);
right after a frame when the rate allows, else as soon as it does
    ``{prefix}/{robot}/map/esdf``          EsdfGrid: the 2-D slice (``output`` 2d or both) or the 3-D grid (3d)
    ``{prefix}/{robot}/map/esdf3d``        EsdfGrid: the 3-D grid when ``output = both`` (additive key)
    ``{prefix}/{robot}/map/objects``       TrackedObjects: people and animals with velocities, after each
                                           ESDF and with its header (``objects.py``; ``object_tracking``)
Serves
    ``{prefix}/{robot}/map/esdf/query``    DistanceQuery → DistanceReply (with ``in_map``), from the
                                           grid published on ``map/esdf``

The ESDF header carries the stamp of the newest frame that changed the map (a re-sent keyframe or a
frame with no usable pixel does not), also when the grid is only re-published (a risk config, a
recentring, a keyframe update, people decaying): its content age seen by the safety filter includes
perception latency and keeps growing while perception is silent. A rejected frame (non-rigid pose, absurd size,
a stamp more than ``clock_tolerance_s`` ahead of this clock) is counted (``rejected_frames``; the last also in
``future_frames``) and logged at most once per period, and changes nothing; the node keeps serving.
A risk file (``risk_file``, see ``runtime.risk_file``) is loaded at start and re-read when it
changes; a bad change keeps the configuration in force and is counted (``risk_errors``). Whatever
a configuration says, what the map holds stays an obstacle of at least the last group
(``RiskConfig``'s floor); one naming no obstacle does not decode (counted in ``NodeStatus.invalid``),
one the mapper cannot use is counted in ``risk_refused``. The configuration in force has a version
and a hash (``RiskStore``), echoed in ``status/mapping`` (``NodeStatus.risk_version``, ``risk_hash``)
and, with ``state_dir``, kept there and reloaded at the next start.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from riskfield.protocol import (
    DistanceQuery,
    DistanceReply,
    Header,
    Limits,
    PerceptionFrame,
    RiskConfig,
    RobotState,
    TrackedObjects,
)

from ..runtime.continuity import StateGate, report_refused
from ..runtime.memory import keep_freed_heap
from ..runtime.node import Node
from ..runtime.rate import TokenBucket
from ..runtime.risk_file import RiskStore, watch_risk_file
from ..runtime.service import ServiceSpec
from .mapper import FrameRejected, FutureFrame, Mapper, MapUpdate
from .objects import ObjectTracker
from .settings import MappingSettings

MAX_QUERY_POINTS = 1_000_000


class MappingNode:
    """Decode → Mapper → encode → publish. Everything runs on the node's single loop thread."""

    def __init__(self, node: Node, settings: MappingSettings):
        self.node, self.s = node, settings
        # The configuration in force, its version and digest, kept under state_dir (module doc).
        self.risk_store = RiskStore(settings.state_dir, node.service, node.log)
        if settings.risk_file is not None:  # a bad file at start is a configuration error
            self.risk_store.commit(watch_risk_file(node, settings.risk_file, settings.risk_poll_s,
                                                   self._set_risk_from_file), str(settings.risk_file))
        keep_freed_heap(settings.heap_keep_mb)  # before the warm-up's first large arrays
        self.mapper = Mapper(settings.mapper_config(), self.risk_store.risk)
        self._show_risk()
        self.mapper.warm_up()
        c = self.mapper.config
        self.tracker = ObjectTracker.warmed(c.objects, c.dynamic) if settings.object_tracking else None
        self.esdf3d_key = node.keys.key(settings.esdf3d_key)
        self.rejected = 0
        self.updates = 0
        self.gate = StateGate.of(settings, settings.clock_tolerance_s)
        node.stats.update(state_refused=0, future_frames=0, risk_refused=0)
        self._period = 1.0 / settings.esdf_rate_hz
        # An average-rate cap that lets a frame that comes a little early through (see rate.py).
        self._bucket = TokenBucket(settings.esdf_rate_hz, burst=2.0)
        k = node.keys
        frame_limits = Limits(max_array_bytes=12 * settings.max_pixels)
        # fifo, not latest: under the keyframe protocol (keyframes.py) a dropped new/updated keyframe
        # would leave its old contribution in the map; 8 bounds the backlog. Frames outside that
        # protocol (tracking frames, senders without ``kind``) keep latest-value semantics in
        # ``on_frame``: one with more than ``frame_backlog`` newer frames queued behind it is
        # skipped, never a longer backlog.
        self._frame_key = k.perception_frame
        node.subscribe(k.perception_frame, PerceptionFrame, self.on_frame, queue="fifo", maxlen=8,
                       limits=frame_limits)
        node.subscribe(k.state, RobotState, self.on_state, queue="latest")
        node.subscribe(k.state_relocalise, RobotState, self.on_relocalise, queue="fifo", maxlen=4)
        node.subscribe(k.risk_config, RiskConfig, self.on_risk_config, queue="latest")
        node.queryable(k.esdf_query, DistanceQuery, self.on_query,
                       limits=Limits(max_array_bytes=24 * MAX_QUERY_POINTS))
        # Frames publish at once when the rate allows; the timer catches what the rate deferred.
        node.every(self._period / 2, self.publish_esdf)

    # -- inputs ---------------------------------------------------------------------------------
    def on_frame(self, frame: PerceptionFrame) -> None:
        st = self.node.stats
        if frame.header.stamp_ns > 0:  # where a frame's age goes (demo report, bench latency): sensor
            # stamp → arrival here, and arrival → this handler (queueing and the decode)
            arrival = self.node.arrival_ns or time.time_ns()
            st["frame_arrival_age_ms"] = (arrival - frame.header.stamp_ns) / 1e6
            st["frame_wait_ms"] = (time.time_ns() - arrival) / 1e6
        if frame.kind in (None, "tracking") and self.node.backlog(self._frame_key) > self.s.frame_backlog:
            st["superseded_frames"] = st.get("superseded_frames", 0) + 1
            return
        try:
            latest = time.time_ns() + round(self.s.clock_tolerance_s * 1e9)
            result = self.mapper.integrate_frame(frame, latest_ns=latest)
        except FrameRejected as exc:
            self.rejected += 1
            self.node.stats["rejected_frames"] = self.rejected
            if isinstance(exc, FutureFrame):
                st["future_frames"] += 1
            self.node.ratelog(logging.WARNING, "frame", f"rejected a perception frame: {exc}")
            return
        st["frames"] = self.mapper.frames
        st["integrate_ms"] = result.ms
        st["rays"] = result.rays
        st["shifts"] = self.mapper.shifts
        if frame.kind is not None:  # the keyframe protocol's counters (keyframes.py)
            kf = self.mapper.keyframes
            st.update({f"kf_{k}": v for k, v in kf.counts.items()}, kf_bytes=kf.nbytes,
                      present_clears=self.mapper.present.clears)
        st["decayed_voxels"] = self.mapper.dynamic.decayed_voxels  # people and animals unseen for dynamic_persist_s
        st["forgotten_voxels"] = self.mapper.dynamic.forgotten_voxels  # walkers out of view (dynamic_moving_persist_s)
        self.publish_esdf()  # right away when the rate allows: no waiting for the timer's phase

    def on_state(self, state: RobotState) -> None:
        refused = self.gate.admit(state.position, state.header.stamp_ns, time.monotonic(), time.time_ns())
        if refused is not None:
            self._state_refused(state, refused)
            return
        self.mapper.set_robot_position(np.asarray(state.position))

    def on_relocalise(self, state: RobotState) -> None:
        refused = self.gate.relocalise(state.position, state.header.stamp_ns, time.monotonic(), time.time_ns())
        if refused is not None:
            self._state_refused(state, refused)
            return
        self.node.log.info("relocalised at %s", np.round(state.position, 3).tolist())
        self.mapper.set_robot_position(np.asarray(state.position))

    def _state_refused(self, state: RobotState, reason: str) -> None:
        report_refused(self.node, self.gate, reason, state.position, state.header.stamp_ns,
                       "the volume stays where it is")

    def on_risk_config(self, risk: RiskConfig) -> None:
        # One naming no obstacle never gets here: it does not decode (RiskConfig's floor), and the
        # runtime counts it (NodeStatus.invalid) and logs why.
        try:
            self.mapper.set_risk_config(risk)
        except ValueError as exc:
            self.node.stats["risk_refused"] += 1
            self.node.ratelog(logging.WARNING, "risk", f"rejected a risk config: {exc}; keeping "
                              f"v{self.risk_store.version} {self.risk_store.digest}")
            return
        self.risk_store.commit(risk, self.node.keys.risk_config)
        self._show_risk()

    def _set_risk_from_file(self, risk: RiskConfig) -> None:
        self.mapper.set_risk_config(risk)  # a ValueError keeps the configuration in force
        self.risk_store.commit(risk, str(self.s.risk_file))
        self._show_risk()

    def _show_risk(self) -> None:
        self.node.status_fields.update(risk_version=self.risk_store.version, risk_hash=self.risk_store.digest)
        self.node.stats["risk_version"] = self.risk_store.version

    # -- outputs --------------------------------------------------------------------------------
    def publish_esdf(self) -> None:
        """Rebuild and publish if there is new data and the rate cap (``esdf_rate_hz`` on average) allows."""
        if not self.mapper.dirty or self.mapper.frames == 0:
            return
        if not self._bucket.allow(time.monotonic()):
            self.node.stats["esdf_deferred"] = self.node.stats.get("esdf_deferred", 0) + 1
            return
        update = self.mapper.update_esdf()
        if update is None:
            return
        self.node.publish(self.node.keys.esdf, update.primary)
        if self.mapper.stamp_ns > 0:
            self.node.stats["esdf_content_age_ms"] = (time.time_ns() - self.mapper.stamp_ns) / 1e6
        if update.slice2d is not None and update.grid3d is not None:
            self.node.publish(self.esdf3d_key, update.grid3d)
        self.updates += 1
        st = self.node.stats
        st["esdf_updates"] = self.updates
        for name, ms in update.timings_ms.items():
            st[f"{name}_ms"] = ms
        self.publish_objects(update)  # last: the ESDF and its counters are done whatever happens here

    # -- tracked objects (objects.py): after each ESDF, with its header ---------------------------
    def publish_objects(self, update: MapUpdate) -> None:
        if self.tracker is None or update.occupancy is None:
            return
        t0 = time.perf_counter()
        objects = self.tracker.update_map(self.mapper.reading(update.occupancy))
        self.mapper.dynamic.protected = self.tracker.protected()  # the next decay forgets the rest (T_w)
        self.node.publish(self.node.keys.objects, TrackedObjects(header=update.primary.header.model_copy(),
                                                                 objects=objects))
        self.node.stats.update(objects=len(objects), objects_ms=(time.perf_counter() - t0) * 1e3)

    def on_query(self, query: DistanceQuery) -> DistanceReply:
        if query.points.shape[0] > MAX_QUERY_POINTS:
            raise ValueError(f"a query of {query.points.shape[0]} points is over {MAX_QUERY_POINTS}")
        ans = self.mapper.query(query.points)
        return DistanceReply(header=Header(frame_id=self.mapper.frame_id), distance=ans.distance, gradient=ans.gradient,
                             risk_group=ans.risk_group.astype(np.uint8), in_map=ans.inside)


def setup(node: Node, settings: MappingSettings) -> MappingNode:
    return MappingNode(node, settings)


SERVICE = ServiceSpec("mapping", MappingSettings, setup)
