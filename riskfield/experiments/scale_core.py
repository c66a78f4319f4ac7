"""``riskfield bench scale``: a LIMO driving at a wall through a SLAM of the wrong scale, in closed loop.

No processes: per run a pure, seeded loop at 50 Hz around the real pieces — the sim backend's SLAM
errors (``perception.degrade``: ``SlamWorld`` with scale error s, scale drift and heading drift,
``OdometrySlip``, and the foundation-model depth and label noise of ``Degrader``), perception's
aligner (``perception.alignment.FrameAligner``: Umeyama over a sliding window, the floor plane
before moving), and the filter's supervisor (``safety_filter.supervisor``: the shrunk distance and
the speed cap of ``scale_guard``) with the default unicycle filter.

**The world.** A floor (z = 0) and a wall across the lane whose face is ``distance`` metres ahead of
the camera at the start. The LIMO starts at the origin facing it, its camera where the platform
description mounts it (``protocol.platforms.LIMO.camera``); the operator's reference is 0.4 m/s
straight ahead.

**Perception** at 12.5 Hz: a 64×48 pinhole camera (90° field of view) ray-casts floor and wall
(labels ``floor`` and ``wall``), ``Degrader`` adds range-growing depth noise, confidence and label
noise, ``SlamWorld`` puts the frame into SLAM's world (pointmap × s, pose through the drifting
similarity, plus ``POSE_NOISE`` of tracking jitter per axis), and the aligner moves it into the
odometry frame. **The map** is the wall where the newest aligned frame's wall points in the lane put
it (their median x): the mapper's present layer with the newest frame only. Two ways to align:
``aligned`` (the product: the online estimate, its uncertainty to the filter on
``perception/alignment``) and ``anchored`` (perception with ``align`` off: SLAM's world placed once
at the first image, never rescaled; no alignment reaches the filter).

**The robot**: the filter's command after two steps of delay, the LIMO's acceleration limits
(``crowd_core``'s actuator), integrated by the filter's own model; the filter and the aligner see
wheel odometry (the true motion with ``OdometrySlip``).

**Metrics** per run: the mapped wall's error along the lane, relative to the robot (mapped distance
in odometry minus the true distance) at the first frame, after 1 m of travel and at the stop; the
stopping gap (the wall's face minus the body's front, true); the estimate's final scale error and σ.
Targets: |error| ≤ 5 cm at 3 m after 1 m of travel, and every aligned stopping gap within 3 cm of
the s = 1 run at the same distance.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from riskfield.protocol import RobotState, VelocityCommand, ade20k
from riskfield.protocol.messages import Header
from riskfield.protocol.platforms import LIMO
from riskfield.services.fields import AnalyticField
from riskfield.services.geometry.camera import T_base_camera
from riskfield.services.geometry.shapes import Plane
from riskfield.services.geometry.transforms import pose_matrix
from riskfield.services.perception.alignment import AlignerConfig, FrameAligner, Similarity, align_frame
from riskfield.services.perception.degrade import DegradationConfig, Degrader, OdometrySlip, SlamErrorConfig, SlamWorld
from riskfield.services.safety_filter.config import FilterConfig
from riskfield.services.safety_filter.filter import SafetyFilter
from riskfield.services.safety_filter.scale_guard import ScaleGuardConfig
from riskfield.services.safety_filter.state import FilterState
from riskfield.services.safety_filter.supervisor import FilterSupervisor

from .crowd_core import COMMAND_DELAY_STEPS, _towards

SCALES = (0.8, 0.87, 1.0, 1.15, 1.25)
DISTANCES = (1.0, 2.0, 3.0, 4.0)
MODES = ("aligned", "anchored")
RATE_HZ = 50.0
FRAME_EVERY = 4  # steps: 12.5 Hz perception
V_REF = 0.4
WIDTH, HEIGHT, HFOV_DEG = 64, 48, 90.0
MAX_DEPTH = 6.0
POSE_NOISE = 0.003  # m per axis of SLAM tracking jitter
LANE = 0.3  # m either side of the robot's line whose wall points place the wall
MAX_S = 40.0
STOP_SPEED, STOP_HOLD_S = 0.01, 1.0
GAP_TOLERANCE, ERROR_TARGET = 0.03, 0.05
FLOOR, WALL = ade20k.index("floor"), ade20k.index("wall")
RESULTS_BEGIN, RESULTS_END = "<!-- scale:begin -->", "<!-- scale:end -->"
GROUPS = ["high", "mid", "low"]


@dataclass(frozen=True)
class Camera:
    fx: float
    fy: float
    cx: float
    cy: float
    rays: np.ndarray  # (H, W, 3), z = 1

    @classmethod
    def default(cls) -> Camera:
        fx = (WIDTH / 2) / math.tan(math.radians(HFOV_DEG / 2))
        cx, cy = (WIDTH - 1) / 2, (HEIGHT - 1) / 2
        v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
        rays = np.stack([(u - cx) / fx, (v - cy) / fx, np.ones_like(u)], axis=-1)
        return cls(fx, fx, cx, cy, rays)


def render(cam: Camera, T_WC: np.ndarray, wall_x: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points in the camera frame, labels, valid) of the floor z = 0 and the wall x = ``wall_x``."""
    d = cam.rays @ T_WC[:3, :3].T
    c = T_WC[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[..., 2] < -1e-9, -c[2] / d[..., 2], np.inf)
        t_wall = np.where(d[..., 0] > 1e-9, (wall_x - c[0]) / d[..., 0], np.inf)
    t = np.minimum(t_floor, t_wall)
    valid = np.isfinite(t) & (t > 0) & (t <= MAX_DEPTH)
    labels = np.where(t_wall <= t_floor, WALL, FLOOR).astype(np.uint16)
    points = (cam.rays * np.where(valid, t, 0.0)[..., None]).astype(np.float32)
    return points, labels, valid


def _odom_state(p: np.ndarray, true: FilterState, slip: float) -> FilterState:
    return FilterState(p.copy(), true.rotation.copy(), true.velocity * (1.0 + slip), true.angular_velocity.copy())


def run(scale: float, distance: float, mode: str = "aligned", seed: int = 0, drift: bool = True,
        max_s: float = MAX_S) -> dict[str, Any]:
    """One closed-loop run (module doc); its metrics."""
    wall0 = time.perf_counter()
    dt = 1.0 / RATE_HZ
    T_BC = T_base_camera(LIMO.camera)
    wall_x = float(T_BC[0, 3] + distance)
    cam = Camera.default()
    errors = SlamErrorConfig.bench(scale) if drift else SlamErrorConfig(scale)
    slam = SlamWorld(errors, seed)
    slip = OdometrySlip(errors.odom_slip)
    degrader = Degrader(DegradationConfig(), seed)
    rng = np.random.default_rng([seed, 7])
    aligner = FrameAligner(T_BC, LIMO.camera.height_sigma, AlignerConfig())
    anchor: Similarity | None = None
    sup = FilterSupervisor(SafetyFilter(FilterConfig(), warm_up=False), 0.3, 0.3, 0.2,
                           scale_guard=ScaleGuardConfig())
    model = sup.filter.model
    true = FilterState.planar(0.0, 0.0, 0.0)
    odom_p = true.position.copy()
    slip.pose(pose_matrix(0.0, 0.0))
    queue = [np.zeros(2)] * COMMAND_DELAY_STEPS
    v_act = w_act = 0.0
    first_err = err_1m = last_err = scale_err_1m = err_1m_true = None
    uncertain_steps = capped_s = 0.0
    still = 0.0
    fallbacks: dict[str, int] = {}
    frames = 0
    t = 0.0
    for k in range(round(max_s * RATE_HZ)):
        t = k * dt
        odom = _odom_state(odom_p, true, errors.odom_slip)
        T_odom_base = pose_matrix(odom_p[0], odom_p[1], 0.0, true.yaw)
        if k % FRAME_EVERY == 0:
            stamp = round(t * 1e9) + 1
            T_true = pose_matrix(true.position[0], true.position[1], 0.0, true.yaw) @ T_BC
            points, labels, valid = render(cam, T_true, wall_x)
            obs = degrader.observe(points, labels, T_true, valid)
            slam.step(T_true)
            T_slam, factor = slam.to_slam(T_true)
            T_slam[:3, 3] += rng.normal(0.0, POSE_NOISE, 3)
            conf = np.where(obs.valid, obs.confidence, np.float32(0.0)).astype(np.float32)
            from riskfield.protocol import PerceptionFrame

            frame = PerceptionFrame(header=Header(stamp_ns=stamp), T_WC=T_slam,
                                    points=(obs.points * np.float32(factor)).astype(np.float32), confidence=conf,
                                    labels=obs.labels, keyframe_id=0, kind="tracking")
            aligner.odometry.on_state(RobotState(header=Header(stamp_ns=stamp), position=tuple(odom_p.tolist()),
                                                 orientation=(0.0, 0.0, math.sin(true.yaw / 2), math.cos(true.yaw / 2)),
                                                 linear_velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0)))
            if mode == "aligned":
                out = aligner.align([frame], stamp)
                if aligner.last is not None:
                    sup.on_alignment(aligner.last.message(stamp), t)
            else:
                if anchor is None:  # SLAM's world put at the first image's odometry camera, rigidly
                    T_odom_cam = T_odom_base @ T_BC
                    R = T_odom_cam[:3, :3] @ T_slam[:3, :3].T
                    anchor = Similarity(1.0, R, T_odom_cam[:3, 3] - R @ T_slam[:3, 3])
                out = [align_frame(frame, anchor)]
            if out:
                f = out[0]
                lab = np.asarray(f.labels).reshape(-1)
                c = np.asarray(f.confidence).reshape(-1)
                world = np.asarray(f.points, np.float64).reshape(-1, 3) @ f.T_WC[:3, :3].T + f.T_WC[:3, 3]
                pick = (lab == WALL) & (c > 0) & (np.abs(world[:, 1] - odom_p[1]) < LANE) & (world[:, 2] > 0.02)
                if pick.sum() >= 5:
                    mapped_x = float(np.median(world[pick, 0]))
                    # in odometry's frame, the one the filter works in: its metre is (1 + slip) true ones
                    err = (mapped_x - odom_p[0]) - (1 + errors.odom_slip) * (wall_x - true.position[0])
                    first_err = err if first_err is None else first_err
                    last_err = err
                    if err_1m is None and true.position[0] >= 1.0:
                        err_1m = err
                        err_1m_true = (mapped_x - odom_p[0]) - (wall_x - true.position[0])
                        if mode == "aligned" and aligner.last is not None:
                            scale_err_1m = aligner.last.similarity.scale * slam.scale / (1 + errors.odom_slip) - 1
                    sup.on_map(AnalyticField(Plane.through([mapped_x, 0.0, 0.0], [-1.0, 0.0, 0.0], label=3),
                                             groups=GROUPS), t)
                    frames += 1
        sup.on_state(odom, t)
        sup.on_ref(VelocityCommand(linear=(V_REF, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="bench"), t)
        cmd, status = sup.tick(t)
        if status.fallback is not None:
            fallbacks[status.fallback] = fallbacks.get(status.fallback, 0) + 1
        uncertain_steps += status.scale_uncertain
        capped_s += dt if status.speed_cap is not None and cmd.linear[0] >= status.speed_cap - 1e-9 else 0.0
        queue.append(np.array([cmd.linear[0], cmd.angular[2]]))
        u = queue.pop(0)
        v_act = _towards(v_act, float(np.clip(u[0], -LIMO.max_linear, LIMO.max_linear)), LIMO.max_accel, dt)
        w_act = _towards(w_act, float(np.clip(u[1], -LIMO.max_angular, LIMO.max_angular)), LIMO.max_yaw_accel, dt)
        before = true.position.copy()
        true = model.integrate(true, np.array([v_act, w_act]), dt)
        odom_p = odom_p + (1.0 + errors.odom_slip) * (true.position - before)
        still = still + dt if abs(v_act) < STOP_SPEED and t > 1.0 else 0.0
        if still >= STOP_HOLD_S:
            break
    est = aligner.last if mode == "aligned" else None
    return {
        "scale": scale, "distance": distance, "mode": mode, "seed": seed, "drift": drift,
        "gap": float(wall_x - (true.position[0] + LIMO.length / 2)),
        "travelled": float(true.position[0]),
        "error_first": first_err, "error_1m": err_1m, "error_stop": last_err, "scale_error_1m": scale_err_1m,
        "error_1m_true": err_1m_true,
        # odometry's scale is the reference: the map is right when it matches odometry, slip included
        "scale_error": None if est is None else float(est.similarity.scale * slam.scale / (1 + errors.odom_slip) - 1),
        "scale_sigma": None if est is None else float(est.scale_sigma),
        "uncertain_s": uncertain_steps * dt, "capped_s": capped_s, "frames": frames, "stopped": still >= STOP_HOLD_S,
        "time_s": t, "fallbacks": fallbacks, "wall_s": time.perf_counter() - wall0,
    }


def run_all(scales: tuple[float, ...] = SCALES, distances: tuple[float, ...] = DISTANCES, seed: int = 0,
            drift: bool = True, modes: tuple[str, ...] = MODES) -> list[dict[str, Any]]:
    return [run(s, d, m, seed, drift) for m in modes for d in distances for s in scales]


def summarise(rows: list[dict[str, Any]], wall_s: float) -> dict[str, Any]:
    """Rows plus each aligned run's difference from the s = 1 run at its distance, and the targets."""
    ref = {(r["mode"], r["distance"]): r["gap"] for r in rows if r["scale"] == 1.0}
    for r in rows:
        base = ref.get((r["mode"], r["distance"]))
        r["gap_vs_s1"] = None if base is None else r["gap"] - base
    aligned = [r for r in rows if r["mode"] == "aligned"]
    at3 = [r for r in aligned if r["distance"] == 3.0 and r["error_1m"] is not None]
    worst_gap = max((abs(r["gap_vs_s1"]) for r in aligned if r["gap_vs_s1"] is not None), default=None)
    # both frames: odometry's (the filter's) and the true one
    worst_err = max((max(abs(r["error_1m"]), abs(r.get("error_1m_true") or 0.0)) for r in at3), default=None)
    return {
        "rows": rows, "wall_s": wall_s,
        "worst_gap_vs_s1": worst_gap, "worst_error_3m_after_1m": worst_err,
        "gap_target_met": worst_gap is not None and worst_gap <= GAP_TOLERANCE,
        "error_target_met": worst_err is not None and worst_err <= ERROR_TARGET,
    }


def _f(v: Any, digits: int = 3, signed: bool = False) -> str:
    if v is None:
        return "–"
    return f"{v:+.{digits}f}" if signed else f"{v:.{digits}f}"


def table(summary: dict[str, Any]) -> str:
    rows = summary["rows"]
    anchored = {(r["distance"], r["scale"]): r for r in rows if r["mode"] == "anchored"}
    lines = ["| wall at (m) | s | anchored: gap (m) | aligned: gap (m) | aligned gap − s = 1 (m) | "
             "error at start (m) | error after 1 m (m) | same, true metres | error at stop (m) | final scale error | "
             "final σ | speed-capped (s) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in (r for r in rows if r["mode"] == "aligned"):
        a = anchored.get((r["distance"], r["scale"]))
        lines.append(f"| {r['distance']:.0f} | {r['scale']:.2f} | {_f(a['gap'] if a else None)} | {_f(r['gap'])} | "
                     f"{_f(r['gap_vs_s1'], signed=True)} | {_f(r['error_first'], signed=True)} | "
                     f"{_f(r['error_1m'], signed=True)} | {_f(r.get('error_1m_true'), signed=True)} | "
                     f"{_f(r['error_stop'], signed=True)} | "
                     f"{_f(r['scale_error'], 4, signed=True)} | {_f(r['scale_sigma'], 4)} | {r['capped_s']:.1f} |")
    return "\n".join(lines)


def section_body(summary: dict[str, Any]) -> list[str]:
    g, e = summary["worst_gap_vs_s1"], summary["worst_error_3m_after_1m"]
    return [
        table(summary), "",
        f"`riskfield bench scale`: {len(summary['rows'])} runs in {summary['wall_s']:.0f} s wall; SLAM errors "
        "`SlamErrorConfig.bench(s)` (scale drift 1 %/√m, heading drift 0.01 rad/√m, odometry slip 1 %, seed 0), "
        f"{POSE_NOISE * 1e3:.0f} mm of tracking jitter, the default depth and label noise, 0.4 m/s towards a wall "
        "(`riskfield/experiments/scale_core.py` defines the loop and each metric; the map is the wall where the "
        "newest aligned frame puts it, no mapper). *anchored*: SLAM's world placed once at the first image and "
        "never rescaled (alignment off; a negative gap is a collision); *aligned*: perception's online "
        "estimate (Umeyama over a 1.5 m window, the floor plane before moving) and the filter's shrunk distance "
        "and 0.2 m/s cap until it converges. Errors: the mapped wall's distance from the robot minus the true one, "
        "in odometry's frame (the filter's: with 1 % slip its metre is 1.01 true ones; the map is right when it "
        "agrees with odometry), and after 1 m also in true metres (slip included); scale error: against "
        "odometry's scale. Targets: |error| ≤ 5 cm at 3 m after 1 m of travel "
        f"(worst of both frames {_f(e)} m: {'met' if summary['error_target_met'] else 'MISSED'}), every aligned "
        f"stopping gap within 3 cm of the s = 1 run (worst {_f(g)} m: "
        f"{'met' if summary['gap_target_met'] else 'MISSED'}).",
    ]


def update_results(path: Path, summary: dict[str, Any]) -> None:
    """Rewrite the scale section of ``path`` between its markers, or append it (``--mode stack``: its
    own section)."""
    stack = summary.get("mode") == "stack"
    begin, end = (STACK_BEGIN, STACK_END) if stack else (RESULTS_BEGIN, RESULTS_END)
    heading = ("## Map scale through the stack: `riskfield bench scale --mode stack`" if stack
               else "## Map scale: `riskfield bench scale`")
    text = path.read_text() if path.is_file() else ""
    body = "\n".join([begin, "", *(stack_section_body(summary) if stack else section_body(summary)), "", end])
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.S)
    if pattern.search(text):
        text = pattern.sub(lambda _: body, text, count=1)
    else:
        text = text.rstrip() + f"\n\n{heading}\n\n" + body + "\n"
    path.write_text(text)


STACK_BEGIN, STACK_END = "<!-- scale-stack:begin -->", "<!-- scale-stack:end -->"


def stack_section_body(summary: dict[str, Any]) -> list[str]:
    rows = summary["rows"]
    ref = {r["mode"]: r["gap"] for r in rows if r["scale"] == 1.0}
    lines = ["| s | anchored: gap (m) | aligned: gap (m) | aligned gap − s = 1 (m) | aligned: final σ | "
             "final residual (m) | speed-capped steps |", "|---|---|---|---|---|---|---|"]
    anchored = {r["scale"]: r for r in rows if r["mode"] == "anchored"}
    for r in (r for r in rows if r["mode"] == "aligned"):
        a = anchored.get(r["scale"])
        lines.append(f"| {r['scale']:.2f} | {_f(a['gap'] if a else None)} | {_f(r['gap'])} | "
                     f"{_f(r['gap'] - ref['aligned'] if 'aligned' in ref else None, signed=True)} | "
                     f"{_f(r['scale_sigma'], 4)} | {_f(r['residual'], 4)} | {r['capped_steps']} |")
    return [*lines, "", f"`riskfield bench scale --mode stack`: {len(rows)} drives in {summary['wall_s']:.0f} s wall, "
            f"a wall {rows[0]['distance']:.1f} m ahead of the camera at 0.4 m/s, simulator → perception (`sim`, "
            "`slam_scale` s, scale and heading drift as the core bench, no slip: the simulator's state is both "
            "odometry and the filter's) → mapping → safety filter as processes on one loopback router; a fresh "
            "perception, mapping and filter per drive (a negative gap is a collision). One drive per cell: the "
            "stack's timing moves a drive's gap by centimetres between repeats, so this table shows the anchored "
            "map's collisions and the aligned map's recovery, and the 3 cm target is checked by the core bench "
            "above."]


# -- the same drive through the service stack ------------------------------------------------------

#: ``--mode stack``: the robot's start and the wall's thickness in the stack's scenario
STACK_START_X = -3.5
STACK_WALL_T = 0.2


def stack_scenario(distance: float) -> dict[str, Any]:
    """A 10 × 4 m room, the LIMO at ``STACK_START_X`` facing +x, a wall across the lane whose face is
    ``distance`` m ahead of the camera."""
    face = STACK_START_X + LIMO.camera.position[0] + distance
    return {"name": f"scale_wall_{distance:g}", "room": {"size": [10.0, 4.0], "height": 2.4},
            "robot": {"type": "limo", "start": [STACK_START_X, 0.0, 0.0]},
            "camera": {"width": 128, "height": 96, "hfov_deg": 90,
                       "mount": {"x": LIMO.camera.position[0], "z": LIMO.camera.position[2]}},
            "objects": [{"class": "wall", "position": [face + STACK_WALL_T / 2, 0.0],
                         "size": [STACK_WALL_T, 2.0, 1.0]}]}


def stack_run(stack: Any, scenario: Path, face: float, scale: float, mode: str, drift: bool, seed: int = 0,
              max_s: float = 30.0) -> dict[str, Any]:
    """One drive through simulator → perception (``sim``, SLAM errors on) → mapping → safety filter.
    ``aligned`` runs perception with ``align=true``; ``anchored`` without (its world is then the SLAM
    world anchored at the first camera). Odometry slip is off here: the simulator's state
    is both the odometry perception aligns to and the filter's."""
    from riskfield.experiments.stack import FAST_FILTER, recording
    from riskfield.protocol import Alignment, SafetyStatus
    from riskfield.services.runtime.client import put

    per = ["--set", "geometry=sim", "--set", "labels=sim", "--set", f"slam_scale={scale}", "--set", f"seed={seed}",
           "--set", f"align={'true' if mode == 'aligned' else 'false'}"]
    if drift:
        cfg = SlamErrorConfig.bench(scale)
        per += ["--set", f"scale_drift={cfg.scale_drift}", "--set", f"yaw_drift={cfg.yaw_drift}"]
    stack.start("perception", "perception", per)
    stack.start("mapping", "mapping", ["--set", "esdf_rate_hz=10"])
    stack.start("filter", "safety-filter", FAST_FILTER)
    stack.start("sim", "simulator", ["--set", f"scenario={scenario}", "--set", "camera_hz=10"])
    k = stack.keys
    keys = {"state": (k.state, RobotState), "status": (k.safety_status, SafetyStatus),
            "alignment": (k.alignment, Alignment)}
    ref = VelocityCommand(linear=(V_REF, 0.0, 0.0), angular=(0.0, 0.0, 0.0), source="bench")
    t0 = time.monotonic()
    x = STACK_START_X
    with recording(stack.session, keys) as rec:
        still_since = None
        while time.monotonic() - t0 < max_s:
            put(stack.session, k.cmd_ref, ref)
            time.sleep(0.05)  # the operator's 20 Hz stick
            states = rec.snapshot("state")
            if not states:
                continue
            s = states[-1][1]
            x = float(s.position[0])
            moving = abs(float(s.linear_velocity[0])) >= STOP_SPEED
            if x - STACK_START_X > 0.05 and not moving:
                still_since = still_since or time.monotonic()
                if time.monotonic() - still_since >= 1.5:
                    break
            else:
                still_since = None
        statuses = [m for _, m in rec.snapshot("status")]
        alignments = [m for _, m in rec.snapshot("alignment")]
    for label in ("sim", "filter", "mapping", "perception"):
        stack.stop(label)
    return {"scale": scale, "distance": face - STACK_START_X - LIMO.camera.position[0], "mode": mode,
            "gap": face - (x + LIMO.length / 2), "travelled": x - STACK_START_X,
            "uncertain_steps": sum(st.scale_uncertain for st in statuses),
            "capped_steps": sum(st.speed_cap is not None for st in statuses),
            "brakes": sum(st.fallback is not None and st.fallback != "slack" for st in statuses),
            "margin_at_stop": statuses[-1].distance_margin if statuses else None,
            "scale_sigma": alignments[-1].scale_sigma if alignments else None,
            "residual": alignments[-1].residual if alignments else None,
            "wall_s": time.monotonic() - t0}


def run_stack(scales: tuple[float, ...], distance: float, out: Path, drift: bool = True, seed: int = 0,
              modes: tuple[str, ...] = MODES) -> list[dict[str, Any]]:
    """``stack_run`` for each mode and scale, at one distance (a fresh stack of services per run)."""
    import yaml

    from riskfield.experiments.stack import Stack

    out.mkdir(parents=True, exist_ok=True)
    scenario = out / f"scale_wall_{distance:g}.yaml"
    spec = stack_scenario(distance)
    scenario.write_text(yaml.safe_dump(spec))
    face = spec["objects"][0]["position"][0] - STACK_WALL_T / 2
    rows = []
    with Stack(robot="scale_bench") as stack:
        for m in modes:
            for s in scales:
                rows.append(stack_run(stack, scenario, face, s, m, drift, seed))
    return rows
