"""The ``sim`` perception backend: the simulator's ground truth, degraded like a foundation model
(``degrade``), then fused into keyframes with the paper's rules (``fusion``) exactly as the
MASt3R-SLAM front end would — only the pixel matches come from geometry instead of a network.

Per frame:

1. degrade the perfect pointmap, labels and pose (noise, confidence, label errors, drift);
2. match every keyframe pixel ξ to the current frame: project its **true** world point into the
   current camera and accept the pixel it lands on if the true depth there agrees (not occluded)
   — this is ``idx_f2k``/``valid_match_k`` of MASt3R-SLAM; the match quality
   ``Qk = sqrt(C_k · C_t[idx_f2k])`` mirrors its ``sqrt(Qff[idx_f2k] · Qkf)``;
3. start a new keyframe when too few keyframe pixels are matched (overlap) or the camera moved or
   turned too far; otherwise fuse: the frame's noisy points, moved into the keyframe frame, into
   the keyframe pointmap by eq. (2), and its labels through ``idx_f2k`` by the vote rule
   (eq. 7–8), both over trusted matches (``valid_match_k & Qk > Q_conf``);
4. publish the current frame — its own pose and pointmap, as MASt3R-SLAM's tracker leaves them on
   the frame (``mast3r_slam/tracker.py``, ``FrameTracker.track``: ``frame.update_pointmap(Xff,
   Cff)``) — with the keyframe's fused labels carried back onto trusted matches; with
   ``publish = "keyframe"`` (default) also the keyframe's fused points there (eq. 2's denoised
   geometry, moved into the current camera), with ``publish = "frame"`` the frame's own points
   everywhere. Or follow the keyframe map-update protocol (``publish = "updates"``, see the
   README): ``keyframe_new`` once per keyframe, ``keyframe_update`` (full pointmap) every
   ``update_every`` fused frames and when the next keyframe starts, ``tracking`` (the current
   frame's own pointmap and pose) otherwise. Never the keyframe's fused pointmap under a newer
   frame's stamp: the map would show the keyframe's moment as the present (a person 1.5 m from
   where they are, a departed one kept as a ghost).

**Drift and correction** (``publish = "updates"``, ``correct_every`` = n > 0): with pose drift on
(``drift_t``, ``drift_yaw``), every n-th new keyframe triggers a simulated loop closure: the drift is
reset and every keyframe still kept (the last ``max_keyframes``) is re-posed to its true pose and
sent again as ``keyframe_update`` — the traffic a SLAM back end's global optimisation produces.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from riskfield.protocol import Image, PerceptionFrame, decode, encode
from riskfield.protocol.messages import Header

from ..geometry.camera import PinholeCamera
from ..geometry.transforms import inverse as _inv
from ..geometry.transforms import transform_points
from ..runtime.jit import require_numba
from . import kernels
from .backend import Labeller, image_rgb
from .degrade import DegradationConfig, Degrader, Observation, SlamErrorConfig, SlamWorld
from .fusion import Q_CONF, KeyframeFusion


@dataclass(frozen=True)
class SimBackendConfig:
    degradation: DegradationConfig = field(default_factory=DegradationConfig)
    publish: str = "keyframe"  # or "frame", "updates" (module doc, step 4)
    kf_min_overlap: float = 0.6  # fraction of the keyframe's valid pixels still matched
    kf_max_translation: float = 1.0  # m
    kf_max_rotation_deg: float = 30.0
    Q_conf: float = Q_CONF
    depth_tol_abs: float = 0.03  # m: occlusion test of a reprojected keyframe point
    depth_tol_rel: float = 0.03  # of the depth
    seed: int = 0
    frame_id: str = "map"
    correct_every: int = 0  # publish = "updates": a loop closure every n keyframes (0: never)
    update_every: int = 5  # publish = "updates": re-send the refined keyframe every n fused frames
    max_keyframes: int = 32  # publish = "updates": keyframes kept for corrections
    c_conf: float = 0.0  # pixels below this confidence are sent with confidence 0
    slam: SlamErrorConfig = field(default_factory=SlamErrorConfig)  # SLAM's scale and heading errors (off)

    def __post_init__(self) -> None:
        if self.publish not in ("keyframe", "frame", "updates"):
            raise ValueError(f"publish {self.publish!r}: use keyframe, frame or updates")
        if self.correct_every < 0 or self.update_every < 1 or self.max_keyframes < 1:
            raise ValueError("correct_every ≥ 0, update_every ≥ 1 and max_keyframes ≥ 1")
        if not 0 <= self.kf_min_overlap <= 1:
            raise ValueError("kf_min_overlap is a fraction")


@dataclass
class _Keyframe:
    fusion: KeyframeFusion
    T_WK_true: np.ndarray
    T_WK: np.ndarray  # as published (with drift)
    world_true: np.ndarray  # (N, 3) true world point of each keyframe pixel
    valid: np.ndarray  # (N,)
    C0: np.ndarray  # (N,) confidence of the keyframe's own observation


@dataclass
class Matches:
    idx_f2k: np.ndarray
    valid_match_k: np.ndarray
    Qk: np.ndarray
    overlap: float


class SimBackend:
    needs_truth = True

    def __init__(self, config: SimBackendConfig | None = None, labeller: Labeller | None = None):
        require_numba("the sim backend")
        self.config = config or SimBackendConfig()
        self.degrader = Degrader(self.config.degradation, self.config.seed)
        self.labeller = labeller
        self.keyframe: _Keyframe | None = None
        self.n_keyframes = 0
        self.frames = 0
        self.last_matches: Matches | None = None
        self.last_observation: Observation | None = None
        self.kept: dict[int, _Keyframe] = {}  # publish = "updates": keyframes a correction re-poses
        self.since_update = 0
        self.corrections = 0
        #: SLAM's world (``degrade.SlamWorld``), None when it is the true one (the default)
        self.slam = None if self.config.slam.is_identity else SlamWorld(self.config.slam, self.config.seed)

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels before the first camera frame: a
        throwaway backend of the same configuration fuses two frames of a plane, decoded from the
        wire like the node's (read-only arrays are a kernel signature of their own)."""
        h, w = 12, 16
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        points = np.stack([(u - w / 2) / w, (v - h / 2) / w, np.ones((h, w))], axis=-1) * 2.0
        truth = PerceptionFrame(T_WC=np.eye(4), points=points.astype(np.float32), keyframe_id=0,
                                confidence=np.ones((h, w), np.float32), labels=np.zeros((h, w), np.uint16))
        # and compact (depth + intrinsics, the simulator's sim/truth): a rebuilt, writable pointmap
        compact = truth.model_copy(update={"points": None, "depth": points[..., 2].astype(np.float32),
                                           "intrinsics": (w / 2, w / 2, w / 2, h / 2)})
        for t in (truth, compact):
            scratch = SimBackend(self.config)
            for i in range(2):
                scratch.process(None, decode(encode(t), PerceptionFrame), i + 1)

    # -- the steps ------------------------------------------------------------------------------
    def match(self, kf: _Keyframe, truth_points: np.ndarray, truth_valid: np.ndarray, T_WC_true: np.ndarray,
              C_t: np.ndarray) -> Matches:
        """Keyframe pixel → current pixel by reprojecting true keyframe points (see module doc;
        ``kernels.match_kernel``)."""
        h, w = truth_valid.shape
        n = kf.world_true.shape[0]
        idx, valid, Qk = np.empty(n, np.int64), np.empty(n, bool), np.empty(n, np.float64)
        cam = self._camera
        truth = (np.ascontiguousarray(truth_points).reshape(-1, 3), np.ascontiguousarray(truth_valid).reshape(-1),
                 np.ascontiguousarray(C_t, np.float32).reshape(-1))
        n_valid = kernels.match_kernel(np.ascontiguousarray(_inv(T_WC_true)), (kf.world_true, kf.valid, kf.C0), truth,
                                       (h, w, float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)),
                                       (float(self.config.depth_tol_abs), float(self.config.depth_tol_rel)),
                                       (idx, valid, Qk))
        return Matches(idx, valid, Qk, float(n_valid) / max(1, int(kf.valid.sum())))

    def _intrinsics(self, points: np.ndarray, valid: np.ndarray,
                    intrinsics: tuple[float, float, float, float] | None = None) -> None:
        h, w = valid.shape
        if intrinsics is not None:  # the simulator's (strided) camera, as the truth carries it
            self._camera = PinholeCamera(w, h, *intrinsics)
            self._k_shape = (h, w)
            return
        if getattr(self, "_k_shape", None) == (h, w):
            return
        # A truth without K (full pointmaps): recover it from the pointmap (x/z is affine in u, y/z in v).
        vv, uu = np.nonzero(valid)
        vv, uu = vv[::7], uu[::7]  # plenty of pixels for a 2-parameter line fit
        if vv.size < 3:
            raise ValueError("a frame with fewer than 3 valid pixels")
        p = points[vv, uu].astype(np.float64)
        xz, yz = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
        a = np.polyfit(uu, xz, 1) if np.ptp(uu) > 0 else np.array([1.0, 0.0])
        b = np.polyfit(vv, yz, 1) if np.ptp(vv) > 0 else np.array([1.0, 0.0])
        self._camera = PinholeCamera(w, h, 1.0 / a[0], 1.0 / b[0], -a[1] / a[0], -b[1] / b[0])
        self._k_shape = (h, w)

    def _new_keyframe(self, obs: Observation, truth_points: np.ndarray, T_WC_true: np.ndarray) -> _Keyframe:
        h, w = obs.valid.shape
        world = transform_points(T_WC_true, truth_points.reshape(-1, 3))
        fusion = KeyframeFusion(self.n_keyframes, h, w, obs.points, obs.confidence, obs.labels,
                                label_weight=np.where(obs.valid.reshape(-1), obs.confidence.reshape(-1), 0.0))
        self.n_keyframes += 1
        return _Keyframe(fusion, T_WC_true.copy(), obs.T_WC.copy(), world, obs.valid.reshape(-1).copy(),
                         obs.confidence.reshape(-1).astype(np.float64))

    def _needs_keyframe(self, kf: _Keyframe, m: Matches, T_WC_true: np.ndarray) -> bool:
        rel = _inv(kf.T_WK_true) @ T_WC_true
        angle = np.degrees(np.arccos(np.clip((np.trace(rel[:3, :3]) - 1) / 2, -1.0, 1.0)))
        return (m.overlap < self.config.kf_min_overlap or np.linalg.norm(rel[:3, 3]) > self.config.kf_max_translation
                or angle > self.config.kf_max_rotation_deg)

    # -- the interface --------------------------------------------------------------------------
    def process(self, image: Image | None, truth: PerceptionFrame | None, stamp_ns: int) -> list[PerceptionFrame]:
        frames = self._process(image, truth, stamp_ns)
        if self.slam is None or truth is None:
            return frames
        # Everything leaves in SLAM's world: poses through its similarity, pointmaps at its scale.
        self.slam.step(np.asarray(truth.T_WC, np.float64))
        out = []
        for f in frames:
            T, k = self.slam.to_slam(np.asarray(f.T_WC, np.float64))
            update: dict[str, object] = {"T_WC": T}
            if f.points is not None:
                update["points"] = (np.asarray(f.points, np.float32) * np.float32(k)).astype(np.float32)
            if f.depth is not None:
                update["depth"] = (np.asarray(f.depth, np.float32) * np.float32(k)).astype(np.asarray(f.depth).dtype)
            out.append(f.model_copy(update=update))
        return out

    def _process(self, image: Image | None, truth: PerceptionFrame | None, stamp_ns: int) -> list[PerceptionFrame]:
        if truth is None:
            return []
        points = np.asarray(truth.pointmap())  # compact truths (depth + intrinsics) at the mapping's stride
        valid = (np.asarray(truth.confidence) > 0) & (points[..., 2] > 0)
        T_WC_true = np.asarray(truth.T_WC, np.float64)
        self._intrinsics(points, valid, truth.intrinsics)
        obs = self.degrader.observe(points, np.asarray(truth.labels), T_WC_true, valid)
        if self.labeller is not None and image is not None:
            labels = self.labeller(image_rgb(image))
            sv, su = labels.shape[0] // valid.shape[0], labels.shape[1] // valid.shape[1]
            if sv >= 1 and su >= 1 and labels[::sv, ::su].shape == valid.shape:
                labels = labels[::sv, ::su]  # the truth's pixels 0, s, 2s, … of the image
            if labels.shape != valid.shape:
                raise ValueError(f"labeller returned {labels.shape}, the frame is {valid.shape}")
            obs.labels = np.where(valid, labels, obs.labels).astype(np.uint16)
        self.last_observation = obs
        self.frames += 1
        kf = self.keyframe
        m = None
        if kf is not None and kf.fusion.height == valid.shape[0] and kf.fusion.width == valid.shape[1]:
            m = self.match(kf, points, valid, T_WC_true, obs.confidence)
            if self._needs_keyframe(kf, m, T_WC_true):
                m = None
        if self.config.publish == "updates":
            if m is not None:
                assert kf is not None
                self._forget_gone(kf, points, valid, T_WC_true)
            return self._updates(kf, m, obs, points, T_WC_true, stamp_ns)
        if m is None:
            kf = self.keyframe = self._new_keyframe(obs, points, T_WC_true)
            self.last_matches = None
        else:
            assert kf is not None
            self._fuse(kf, m, obs, T_WC_true)
        return [self._message(kf, obs, m, T_WC_true, stamp_ns)]

    def _forget_gone(self, kf: _Keyframe, truth_points: np.ndarray, truth_valid: np.ndarray,
                     T_WC_true: np.ndarray) -> int:
        """No keyframe outlives what it shows: a keyframe pixel whose surface this frame sees
        *through* (its pixel here sees farther than the keyframe's point, beyond the occlusion
        tolerance: a person who walked away) is dropped from the keyframe (confidence 0, no longer
        matched), so its next ``keyframe_update`` takes the ghost out of the map. A keyframe point
        hidden behind something nearer is only occluded and stays. Returns the pixels dropped."""
        pc = transform_points(_inv(T_WC_true), kf.world_true)
        z = pc[:, 2]
        front = kf.valid & (z > 1e-6)
        h, w = truth_valid.shape
        uv, _ = self._camera.project(np.where(front[:, None], pc, [0.0, 0.0, 1.0]))
        u, v = np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
        inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        idx = np.where(inside, v * w + u, 0)
        tol = self.config.depth_tol_abs + self.config.depth_tol_rel * z
        gone = inside & truth_valid.reshape(-1)[idx] & (truth_points.reshape(-1, 3)[idx, 2] > z + tol)
        n = int(gone.sum())
        if n:
            kf.valid[gone] = False
            kf.fusion.C[gone] = 0.0
        return n

    def _fuse(self, kf: _Keyframe, m: Matches, obs: Observation, T_WC_true: np.ndarray) -> None:
        """The frame fused into the keyframe over trusted matches (module doc, step 3;
        ``kernels.fuse_kernel``): new arrays, so a message built from the previous state keeps it."""
        T_KC = _inv(kf.T_WK_true) @ T_WC_true  # the tracker's relative pose estimate
        f = kf.fusion
        trusted = np.empty(f.C.shape, bool)
        X, C, labels, weights = (np.empty_like(a) for a in (f.X, f.C, f.labels, f.weights))
        frame = (np.ascontiguousarray(obs.points, np.float32).reshape(-1, 3),
                 np.ascontiguousarray(obs.confidence, np.float32).reshape(-1),
                 np.ascontiguousarray(obs.labels, np.uint16).reshape(-1))
        kernels.fuse_kernel(np.ascontiguousarray(T_KC), frame, (m.idx_f2k, m.valid_match_k, m.Qk),
                            float(self.config.Q_conf), (f.X, f.C, f.labels, f.weights),
                            (X, C, labels, weights, trusted))
        f.X, f.C, f.labels, f.weights = X, C, labels, weights
        f.updates += 1
        self.last_matches = m

    def _updates(self, kf: _Keyframe | None, m: Matches | None, obs: Observation, points: np.ndarray,
                 T_WC_true: np.ndarray, stamp_ns: int) -> list[PerceptionFrame]:
        """The keyframe map-update protocol (module doc, step 4, and drift and correction)."""
        c = self.config
        if m is not None:
            assert kf is not None
            self._fuse(kf, m, obs, T_WC_true)
            self.since_update += 1
            if self.since_update >= c.update_every:
                self.since_update = 0
                return [self._keyframe_message(kf, "keyframe_update", stamp_ns)]
            return [self._tracking_message(kf, obs, stamp_ns)]
        out = []
        if kf is not None and self.since_update > 0:  # the finished keyframe's final state
            out.append(self._keyframe_message(kf, "keyframe_update", stamp_ns))
        kf = self.keyframe = self._new_keyframe(obs, points, T_WC_true)
        self.last_matches = None
        self.since_update = 0
        self.kept[kf.fusion.id] = kf
        while len(self.kept) > c.max_keyframes:
            self.kept.pop(min(self.kept))
        out.append(self._keyframe_message(kf, "keyframe_new", stamp_ns))
        if c.correct_every and self.n_keyframes % c.correct_every == 0:
            # A loop closure: every kept keyframe back to its true pose, the drift reset.
            self.corrections += 1
            self.degrader.drift = np.eye(4)
            for k in sorted(self.kept):
                old = self.kept[k]
                if not np.allclose(old.T_WK, old.T_WK_true, atol=1e-9):
                    old.T_WK = old.T_WK_true.copy()
                    out.append(self._keyframe_message(old, "keyframe_update", stamp_ns))
        return out

    def _keyframe_message(self, kf: _Keyframe, kind: str, stamp_ns: int) -> PerceptionFrame:
        f = kf.fusion
        C = f.C.reshape(f.height, f.width)
        return PerceptionFrame(header=Header(stamp_ns=stamp_ns, frame_id=self.config.frame_id), T_WC=kf.T_WK,
                               points=f.X.reshape(f.height, f.width, 3),
                               confidence=np.where(C < self.config.c_conf, np.float32(0.0), C),
                               labels=f.labels.reshape(f.height, f.width), keyframe_id=f.id, kind=kind)

    def _tracking_message(self, kf: _Keyframe, obs: Observation, stamp_ns: int) -> PerceptionFrame:
        return PerceptionFrame(header=Header(stamp_ns=stamp_ns, frame_id=self.config.frame_id), T_WC=obs.T_WC,
                               points=obs.points, confidence=obs.confidence, labels=obs.labels,
                               keyframe_id=kf.fusion.id, kind="tracking")

    def _message(self, kf: _Keyframe, obs: Observation, m: Matches | None, T_WC_true: np.ndarray,
                 stamp_ns: int) -> PerceptionFrame:
        """The current frame (module doc, step 4): never the keyframe's moment under a new stamp."""
        f = kf.fusion
        header = Header(stamp_ns=stamp_ns, frame_id=self.config.frame_id)
        cam = self._camera  # the keyframe's pixel grid is the camera's: the same intrinsics
        K = (cam.fx, cam.fy, cam.cx, cam.cy)
        labels, points = (obs.labels, obs.points) if m is None else self._current_frame(kf, obs, m, T_WC_true)
        return PerceptionFrame(header=header, T_WC=obs.T_WC, points=points, confidence=obs.confidence,
                               labels=labels, keyframe_id=f.id, intrinsics=K)

    def _current_frame(self, kf: _Keyframe, obs: Observation, m: Matches,
                       T_WC_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The frame's (labels, points) with the keyframe's fused labels written back at trusted
        matches and, ``publish = "keyframe"``, its fused points there (eq. 2's denoised geometry
        where the frame still sees it, moved into this camera), ``kernels.current_frame_kernel``;
        copies, the observation's own arrays untouched."""
        f = kf.fusion
        keyframe_points = self.config.publish == "keyframe"
        labels = np.array(obs.labels, np.uint16)
        points = np.array(obs.points, np.float32) if keyframe_points else obs.points
        matches = (m.idx_f2k.reshape(-1), m.valid_match_k.reshape(-1), m.Qk.reshape(-1))
        frame = (points.reshape(-1, 3), labels.reshape(-1))  # views of the copies above, written in place
        kernels.current_frame_kernel(np.ascontiguousarray(_inv(T_WC_true) @ kf.T_WK_true), (f.X, f.labels), matches,
                                     float(self.config.Q_conf), keyframe_points, frame)
        return labels, points
