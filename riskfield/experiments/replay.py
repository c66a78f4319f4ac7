"""Recorded perception frames replayed into mapping and the safety filter: the latency of the path
the product owns (``riskfield bench latency --path replay``), without the simulator's rendering
and perception's backend competing for the CPU.

**Recording** (``record``, in this process, before any service starts): the demo's room, the robot
turning on the spot at 10 Hz frames, rendered once per frame. Each render feeds two ``sim``
perception backends: the full-size one (a full-size truth, full-size frames of HxWx3 float32 points)
and the compact one (the simulator's ``sim/truth`` at ``truth_stride``, frames sent as
``perception.compact`` makes them). The compact frames are what is replayed; the full-size ones give
the full message size and the reconstruction error of the compact form (``compact`` of a full-size
frame, rebuilt by ``PerceptionFrame.pointmap``, against its points at the same pixels: the float16
rounding and the points a fused keyframe put off their pixel's ray).

**Replay** (``replay``): mapping and the safety filter as the demo runs them, each in its own
process over a loopback router; this process publishes the recorded frames at the camera rate,
each stamped at its publication (so the ESDF's content stamp is the moment perception would have
published it), the recorded robot state at 50 Hz and an operator's reference at 25 Hz. The
filter's ``SafetyStatus`` says when each step ran (its header stamp) and on what map (its content
age ``esdf_age_ms``: the map's stamp is the stamp minus the age): for each frame, the first step on
an ESDF whose stamp is at least the frame's, the first ``cmd/safe`` computed on a map that contains
it. Every stage is a per-frame distribution from the same run: encode, publish → ESDF arrival
here, ESDF arrival → that step, the total; the nodes' own timings (decode and queue, integrate,
ESDF update) are their 1 Hz status samples. Beside it, ``core_costs`` runs the mapping core on the
same frames in this process and times each stage as CPU time too: on a machine
whose cores other work keeps busy, the difference between that and the wall time is the machine's
share, not the design's.
"""

from __future__ import annotations

import itertools
import threading
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from riskfield.protocol import (
    ENCODING,
    NodeStatus,
    PerceptionFrame,
    RobotState,
    SafetyStatus,
    VelocityCommand,
    decode,
    encode,
)
from riskfield.protocol.keys import qos_of
from riskfield.protocol.messages import Header

from .timing import timing_stats

#: Ranges (m) over which the reconstruction error is reported.
ERROR_RANGE_M = (1.0, 4.0)


@dataclass
class Recording:
    frames: list[PerceptionFrame]
    """The compact frames, as perception publishes them."""
    states: list[RobotState]
    """The robot's state at each frame."""
    full_bytes: list[int] = field(default_factory=list)
    """The full-size frame, encoded."""
    compact_bytes: list[int] = field(default_factory=list)
    errors_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Per pixel at 1–4 m: |compact(full-size frame) rebuilt − full-size point| (m)."""
    truth_bytes: tuple[int, int] = (0, 0)
    """``sim/truth`` encoded: full size, and at ``truth_stride``."""
    process_ms: dict[str, list[float]] = field(default_factory=lambda: {"full": [], "compact": []})
    """The ``sim`` backend's ``process`` of the full-size truth, and of the strided one (+ ``compact``)."""
    codec_ms: dict[str, list[float]] = field(default_factory=lambda: {"full": [], "compact": []})
    """Encode + decode (the receiver's validation included) of the full-size frame and of the compact one."""
    maps: dict[str, Any] = field(default_factory=dict)
    """The ESDF slice built from the full-size frames against those built from their compact form and from
    the compact pipeline's frames (``map_agreement``)."""

    def summary(self) -> dict[str, Any]:
        e = self.errors_m
        return {"frames": len(self.frames), "full_frame_bytes_median": float(np.median(self.full_bytes)),
                "compact_frame_bytes_median": float(np.median(self.compact_bytes)),
                "truth_bytes_full": self.truth_bytes[0], "truth_bytes_strided": self.truth_bytes[1],
                "error_range_m": list(ERROR_RANGE_M), "error_pixels": int(e.size),
                "error_m_median": float(np.median(e)) if e.size else None,
                "error_m_p99": float(np.percentile(e, 99)) if e.size else None,
                "error_m_max": float(e.max()) if e.size else None,
                "codec_round_trip_ms": {k: timing_stats(v) for k, v in self.codec_ms.items()},
                "sim_backend_process_ms": {k: timing_stats(v) for k, v in self.process_ms.items()},
                "map_agreement": self.maps}


def record(n: int, camera_hz: float = 10.0, turn_rad_s: float = 0.4, fmt: str = "float16", seed: int = 0,
           compare: bool = True) -> Recording:
    """``n`` frames of the demo's room (module doc); ``compare``: also the full-size path, for the sizes and errors."""
    from riskfield.services.perception.compact import compact, frame_stride
    from riskfield.services.perception.node import PerceptionSettings
    from riskfield.services.perception.sim_backend import SimBackend, SimBackendConfig
    from riskfield.services.simulator.node import SimulatorSettings, truth_frame
    from riskfield.services.simulator.scenario import load_scenario
    from riskfield.services.simulator.world import World

    from .scenarios import scenario

    stride = int(SimulatorSettings.model_fields["truth_stride"].default)
    pixel_stride = int(PerceptionSettings.model_fields["pixel_stride"].default)
    world = World(load_scenario(scenario()))
    cam = world.camera
    compact_backend, full_backend = SimBackend(SimBackendConfig(seed=seed)), SimBackend(SimBackendConfig(seed=seed))
    rec = Recording([], [])
    errors = []
    mappers = {k: _mapper() for k in ("full", "full_compacted", "compact_pipeline")} if compare else {}
    lo, hi = ERROR_RANGE_M
    for i in range(n):
        world.command(np.zeros(3), np.array([0.0, 0.0, turn_rad_s]))
        world.advance(1.0 / camera_hz)
        r = world.render()
        stamp = 1_000_000_000 + round(i * 1e9 / camera_hz)
        header = Header(stamp_ns=stamp, frame_id="map")
        truth = truth_frame(r, cam, stride, header, i)
        have = frame_stride((cam.height, cam.width), truth.pixels) or 1
        t0 = time.perf_counter()
        made = [compact(f, fmt, max(1, pixel_stride // have))  # type: ignore[arg-type]
                for f in compact_backend.process(None, truth, stamp)]
        rec.frames += made
        rec.process_ms["compact"].append((time.perf_counter() - t0) * 1e3)
        for m in mappers.values():
            m.set_robot_position(np.asarray(world.state().position))
        if mappers:
            for f in made:
                mappers["compact_pipeline"].integrate_frame(decode(encode(f), PerceptionFrame))
        st = world.state()
        rec.states.append(RobotState(header=header, position=tuple(st.position), orientation=tuple(st.orientation),
                                     linear_velocity=tuple(st.linear_velocity),
                                     angular_velocity=tuple(st.angular_velocity)))
        if not compare:
            continue
        full_truth = PerceptionFrame(header=header, T_WC=r.T_WC, points=r.points, confidence=r.valid.astype(np.float32),
                                     labels=r.labels, keyframe_id=i)
        if i == 0:
            rec.truth_bytes = (len(encode(full_truth)), len(encode(truth)))
        t0 = time.perf_counter()
        full_frames = full_backend.process(None, full_truth, stamp)
        rec.process_ms["full"].append((time.perf_counter() - t0) * 1e3)
        for f in full_frames:
            t0 = time.perf_counter()
            payload = encode(f)
            decode(payload, PerceptionFrame)
            t1 = time.perf_counter()
            rec.full_bytes.append(len(payload))
            small = compact(f, fmt, pixel_stride)  # type: ignore[arg-type]
            t2 = time.perf_counter()
            payload = encode(small)
            small = decode(payload, PerceptionFrame)
            small_points = small.pointmap()  # the receiver's rebuild belongs to the round trip
            rec.codec_ms["full"].append((t1 - t0) * 1e3)
            rec.codec_ms["compact"].append((time.perf_counter() - t2) * 1e3)
            rec.compact_bytes.append(len(payload))
            mappers["full"].integrate_frame(f)
            mappers["full_compacted"].integrate_frame(small)
            want = np.asarray(f.points)[::pixel_stride, ::pixel_stride]
            rng = np.linalg.norm(want, axis=-1)
            use = (np.asarray(small.confidence) > 0) & (rng >= lo) & (rng <= hi)
            errors.append(np.linalg.norm(small_points - want, axis=-1)[use])
    rec.errors_m = np.concatenate(errors) if errors else np.zeros(0)
    if mappers:
        grids = {k: m.update_esdf() for k, m in mappers.items()}
        base = grids.pop("full")
        rec.maps = {k: map_agreement(base.primary, g.primary) for k, g in grids.items() if base and g}
    return rec


def _mapper() -> Any:
    from riskfield.protocol import RiskConfig
    from riskfield.services.mapping.mapper import Mapper
    from riskfield.services.mapping.settings import MappingSettings

    return Mapper(MappingSettings().mapper_config(), RiskConfig())


def map_agreement(a: Any, b: Any) -> dict[str, float]:
    """Two ESDF slices of the same volume: |Δ distance| (m) over the cells within 1 m of an obstacle
    and outside it in either (what the filter's barrier reads; deep inside a wall's solid interior
    both are negative and how deep does not matter), median and p99; and the obstacle cells'
    (distance < 0) intersection over union."""
    da, db = np.asarray(a.distance), np.asarray(b.distance)
    if da.shape != db.shape or a.origin != b.origin:
        return {"comparable": 0.0}
    v = float(a.voxel_size)
    near = ((da < 1.0) | (db < 1.0)) & ((da > -v) | (db > -v))
    diff = np.abs(da - db)[near]
    oa, ob = da < 0, db < 0
    return {"comparable": 1.0, "near_cells": float(near.sum()),
            "abs_diff_m_median": float(np.median(diff)) if diff.size else 0.0,
            "abs_diff_m_p99": float(np.percentile(diff, 99)) if diff.size else 0.0,
            "obstacle_iou": float((oa & ob).sum() / max(1, (oa | ob).sum()))}


def core_costs(rec: Recording) -> dict[str, Any]:
    """The design's own cost per frame, apart from what the machine's other load adds: the mapping
    core as the mapping node runs it (its default settings), on the recorded frames in this process,
    decode → integrate → ESDF update, each as the CPU time of this process (``time.process_time``,
    any kernel thread included; nothing else runs here then; time spent waiting for a core is not in
    it) and as wall time; ms."""
    from riskfield.protocol import RiskConfig
    from riskfield.services.mapping.mapper import Mapper
    from riskfield.services.mapping.settings import MappingSettings

    mapper = Mapper(MappingSettings().mapper_config(), RiskConfig())
    mapper.warm_up()
    cpu: dict[str, list[float]] = {"decode": [], "integrate": [], "ESDF update": [], "total": []}
    wall: dict[str, list[float]] = {k: [] for k in cpu}
    for i, f in enumerate(rec.frames):
        mapper.set_robot_position(np.asarray(rec.states[min(i, len(rec.states) - 1)].position))
        payload = encode(f)
        marks = [(time.process_time(), time.perf_counter())]
        frame = decode(payload, PerceptionFrame)
        marks.append((time.process_time(), time.perf_counter()))
        mapper.integrate_frame(frame)
        marks.append((time.process_time(), time.perf_counter()))
        mapper.update_esdf()
        marks.append((time.process_time(), time.perf_counter()))
        for k, (a, b) in zip(("decode", "integrate", "ESDF update"), itertools.pairwise(marks), strict=True):
            cpu[k].append((b[0] - a[0]) * 1e3)
            wall[k].append((b[1] - a[1]) * 1e3)
        cpu["total"].append((marks[-1][0] - marks[0][0]) * 1e3)
        wall["total"].append((marks[-1][1] - marks[0][1]) * 1e3)
    skip = min(10, len(rec.frames) // 5)  # the first frames fill an empty volume
    return {"cpu_ms": {k: timing_stats(v[skip:]) for k, v in cpu.items()},
            "wall_ms": {k: timing_stats(v[skip:]) for k, v in wall.items()}}


def _publisher(session: Any, keys: Any, key: str) -> Any:
    """A publisher with the key's QoS, as ``Node._declare_publisher`` declares the product's."""
    q = qos_of(keys.relative(key))
    return session.declare_publisher(
        key, encoding=zenoh.Encoding(ENCODING), priority=getattr(zenoh.Priority, q.priority.upper()),
        congestion_control=zenoh.CongestionControl.DROP if q.drop else zenoh.CongestionControl.BLOCK,
        express=q.express)


def replay(rec: Recording, services: list[tuple[str, str, list[str]]], camera_hz: float = 10.0,
           warmup: int = 20, turn_rad_s: float = 0.4) -> dict[str, Any]:
    """Publish ``rec``'s frames into ``services`` (label, service, args: mapping and the filter) and
    time them (module doc). The first ``warmup`` frames are published and not counted."""
    from .stack import Stack

    robot = f"bench_{uuid.uuid4().hex[:6]}"
    lock = threading.Lock()
    esdf: list[tuple[int, int]] = []  # (arrival, stamp), wall ns
    steps: list[tuple[int, int, int]] = []  # (arrival, step stamp, map stamp)
    node_extra: dict[str, dict[str, list[float]]] = {}
    sent: list[tuple[int, float, int]] = []  # (stamp, encode ms, put done)
    with Stack(robot) as stack:
        keys = stack.keys
        for label, service, args in services:
            stack.start(label, service, args)
        from riskfield.services.recorder.mcap_io import peek_schema

        def on_esdf(sample: Any) -> None:
            t = time.time_ns()
            meta = peek_schema(sample.payload.to_bytes())
            if meta is not None and meta[1] > 0:
                with lock:
                    esdf.append((t, meta[1]))

        def on_status(sample: Any) -> None:
            t = time.time_ns()
            msg = decode(sample.payload.to_bytes(), SafetyStatus)
            if msg.esdf_age_ms >= 0:
                with lock:
                    steps.append((t, msg.header.stamp_ns, msg.header.stamp_ns - round(msg.esdf_age_ms * 1e6)))

        def on_node_status(sample: Any) -> None:
            msg = decode(sample.payload.to_bytes(), NodeStatus)
            with lock:
                d = node_extra.setdefault(msg.service, {})
                for k, v in msg.extra.items():
                    d.setdefault(k, []).append(v)

        subs = [stack.session.declare_subscriber(keys.esdf, on_esdf),
                stack.session.declare_subscriber(keys.safety_status, on_status),
                stack.session.declare_subscriber(keys.key("status/*"), on_node_status)]
        frames_pub = _publisher(stack.session, keys, keys.perception_frame)
        state_pub = _publisher(stack.session, keys, keys.state)
        ref_pub = _publisher(stack.session, keys, keys.cmd_ref)
        current = [0]
        stop = threading.Event()

        def background() -> None:  # the robot's state at 50 Hz, an operator's reference at 25 Hz
            ref = VelocityCommand(linear=(0.0, 0.0, 0.0), angular=(0.0, 0.0, turn_rad_s), source="bench")
            k = 0
            while not stop.is_set():
                s = rec.states[min(current[0], len(rec.states) - 1)]
                s.header.stamp_ns = time.time_ns()
                state_pub.put(encode(s))
                if k % 2 == 0:  # 25 Hz: well within the filter's reference timeout
                    ref.header.stamp_ns = time.time_ns()
                    ref_pub.put(encode(ref))
                k += 1
                stop.wait(0.02)

        bg = threading.Thread(target=background, daemon=True)
        bg.start()
        try:
            time.sleep(0.5)
            period = 1.0 / camera_hz
            next_t = time.perf_counter()
            for i, f in enumerate(rec.frames):
                current[0] = i
                next_t += period
                f.header.stamp_ns = stamp = time.time_ns()
                f.header.seq = i
                t0 = time.perf_counter()
                payload = encode(f)
                t1 = time.perf_counter()
                frames_pub.put(payload)
                if i >= warmup:
                    sent.append((stamp, (t1 - t0) * 1e3, time.time_ns()))
                time.sleep(max(0.0, next_t - time.perf_counter()))
            time.sleep(1.0)  # what is in flight still arrives
        finally:
            stop.set()
            bg.join(2.0)
            for sub in subs:
                sub.undeclare()
            for p in (frames_pub, state_pub, ref_pub):
                p.undeclare()
    return timings(sent, esdf, steps, node_extra)


def timings(sent: list[tuple[int, float, int]], esdf: list[tuple[int, int]], steps: list[tuple[int, int, int]],
            node_extra: dict[str, dict[str, list[float]]]) -> dict[str, Any]:
    """Per frame (``sent``: its stamp, encode ms, put done): the first ESDF arrival here whose stamp
    is at least the frame's, and the first filter step (``steps``: arrival, step stamp, map stamp)
    on a map at least that new (1 ms of rounding allowed: the age is a float in ms); ms, one run."""
    esdf = sorted(esdf)
    steps = sorted(steps, key=lambda s: s[1])
    total, encode_ms, to_esdf, esdf_to_step, step_to_here, lost = [], [], [], [], [], 0
    for stamp, enc, _done in sent:
        e = next((t for t, s in esdf if s >= stamp), None)
        st = next((s for s in steps if s[2] >= stamp - 1_000_000), None)
        if e is None or st is None:
            lost += 1
            continue
        arrival, step_ns, _ = st
        encode_ms.append(enc)
        total.append((step_ns - stamp) / 1e6)
        to_esdf.append((e - stamp) / 1e6)
        esdf_to_step.append((step_ns - e) / 1e6)
        step_to_here.append((arrival - step_ns) / 1e6)
    work = {"mapping: frame arrives → handled (queue, decode)": ("mapping", "frame_wait_ms"),
            "mapping: stamp → frame arrives": ("mapping", "frame_arrival_age_ms"),
            "mapping integrate": ("mapping", "integrate_ms"), "mapping ESDF update": ("mapping", "total_ms"),
            "mapping: stamp → ESDF published": ("mapping", "esdf_content_age_ms")}
    return {
        "frames": len(sent), "lost": lost,
        "frame_to_cmd_safe_ms": timing_stats(total),
        "stages_ms": {"encode (perception's share)": timing_stats(encode_ms),
                      "published → ESDF arrives here": timing_stats(to_esdf),
                      "ESDF arrives here → the filter's step on it": timing_stats(esdf_to_step),
                      "step → its status arrives here": timing_stats(step_to_here)},
        "node_ms": {label: timing_stats(node_extra.get(svc, {}).get(name, [])) for label, (svc, name) in work.items()},
    }


#: The replay path's target: frame published → first ``cmd/safe`` computed on an ESDF containing it.
FRAME_TO_SAFE_P99_MS = 60.0


def replay_path(console: Any, frames: int = 250, warmup: int = 20, camera_hz: float = 10.0) -> dict[str, Any]:
    """Record, replay into the demo's mapping and filter, print the tables; the ``replay_path`` part
    of ``riskfield bench latency``'s summary."""
    import os

    from rich.table import Table

    from .demo.config import DemoConfig
    from .demo.run import camera_pipeline

    console.print(f"[bold]latency bench, replay path[/bold]: recording {frames} frames of the demo's room "
                  "(the full-size and the compact frame)")
    t0 = time.perf_counter()
    rec = record(frames, camera_hz)
    size = rec.summary()
    console.print(f"recorded in {time.perf_counter() - t0:.0f} s: perception/frame "
                  f"{size['full_frame_bytes_median'] / 1e6:.2f} MB full-size → "
                  f"{size['compact_frame_bytes_median'] / 1e3:.0f} KB compact; sim/truth "
                  f"{size['truth_bytes_full'] / 1e6:.2f} MB → {size['truth_bytes_strided'] / 1e3:.0f} KB; "
                  f"reconstruction error against the full-size frame at {ERROR_RANGE_M[0]:g}–{ERROR_RANGE_M[1]:g} m: "
                  "median "
                  f"{size['error_m_median'] * 1e3:.2f} mm, p99 {size['error_m_p99'] * 1e3:.2f} mm, max "
                  f"{size['error_m_max'] * 1e3:.2f} mm over {size['error_pixels']} pixels; codec round trip "
                  + ", ".join(f"{k} {v['median']:.2f} / {v['p99']:.2f} ms"
                              for k, v in size["codec_round_trip_ms"].items() if v) + " (median / p99); sim backend "
                  + ", ".join(f"{k} {v['median']:.1f} / {v['p99']:.1f} ms"
                              for k, v in size["sim_backend_process_ms"].items() if v))
    for k, m in size["map_agreement"].items():
        if m.get("comparable"):
            console.print(f"ESDF slice after {frames} frames, full-size frames vs {k.replace('_', ' ')}: |Δ distance| "
                          f"within 1 m of obstacles, outside them: median {m['abs_diff_m_median'] * 100:.1f} cm, p99 "
                          f"{m['abs_diff_m_p99'] * 100:.1f} cm; obstacle cells IoU {m['obstacle_iou']:.3f}")
    core = core_costs(rec)
    ct = Table("mapping core, per frame (one run)", "CPU p50 ms", "CPU p99 ms", "wall p50 ms", "wall p99 ms",
               title="the design's share: the mapping node's work as CPU time, and as wall time")
    for k in core["cpu_ms"]:
        c, w = core["cpu_ms"][k], core["wall_ms"][k]
        ct.add_row(k, *(f"{d[q]:.1f}" if d else "–" for d in (c, w) for q in ("median", "p99")))
    console.print(ct)
    services = [s for s in camera_pipeline(DemoConfig()) if s[1] in ("mapping", "safety-filter")]
    lat = replay(rec, services, camera_hz, warmup)
    table = Table("stage (one run, per frame)", "n", "p50 ms", "p90 ms", "p99 ms", "max ms",
                  title=f"perception/frame published → first cmd/safe on its ESDF ({lat['frames']} frames, "
                        f"{camera_hz:g} Hz, {lat['lost']} lost)")

    def row(name: str, st: dict[str, float] | None) -> None:
        cells = [f"{st[k]:.1f}" for k in ("median", "p90", "p99", "max")] if st else ["–"] * 4
        table.add_row(name, str(st["n"]) if st else "0", *cells)

    row("total: published → step computed on an ESDF containing it", lat["frame_to_cmd_safe_ms"])
    for name, st in lat["stages_ms"].items():
        row(name, st)
    for name, st in lat["node_ms"].items():
        row(f"node (1 Hz status): {name}", st)
    console.print(table)
    p99 = (lat["frame_to_cmd_safe_ms"] or {}).get("p99")
    ok = p99 is not None and p99 <= FRAME_TO_SAFE_P99_MS
    console.print(f"frame → cmd/safe p99 {p99 if p99 is None else round(p99, 1)} ms; target ≤ "
                  f"{FRAME_TO_SAFE_P99_MS:g} ms: " + ("[green]met[/green]" if ok else "[red]not met[/red]")
                  + f"; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    return {"frames": size, "core": core, "target_p99_ms": FRAME_TO_SAFE_P99_MS, "target_met": ok,
            "load_average": list(os.getloadavg()), **lat}
