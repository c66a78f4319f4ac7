"""The perception node: ``camera/image`` (+ ``sim/truth`` or ``camera/depth``) → ``perception/frame``.

Settings choose the geometry (``sim`` | ``mast3r`` | ``rgbd``) and the labels (``sim`` |
``efficientvit``). With ``geometry = sim`` each image is paired with the simulator's ground-truth
frame carrying the same ``header.stamp_ns`` (key ``{prefix}/{robot}/sim/truth``, see the simulator
node; at ``truth_stride``, every n-th pixel); with ``geometry = rgbd`` with the ``DepthImage`` of the
same stamp on ``camera/depth``, and ``state`` poses the camera. Images wait at most ``pair_timeout_s``
for their companion. Output frames keep the image's stamp; a frame with intrinsics goes out compact
(``compact``: depth at ``pixel_stride``, ``frame_depth``). A backend that cannot start (unknown name,
missing weights, config, CUDA) stops the node with one line naming what is missing.
"""

from __future__ import annotations

import io
import logging
import time
from collections import OrderedDict
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, ValidationInfo, field_validator

from riskfield.protocol import CERTAIN_CONFIDENCE, DepthImage, Image, Keys, PerceptionFrame, RobotState, ade20k
from riskfield.protocol.platforms import LIMO, CameraMount

from ..geometry.camera import T_base_camera
from ..runtime.node import Node
from ..runtime.service import ServiceSpec, ServiceUnavailable
from ..runtime.settings import NodeSettings
from .alignment import AlignerConfig, FrameAligner
from .backend import Labeller, MissingBackend, PerceptionBackend
from .compact import compact, frame_stride
from .degrade import DegradationConfig, OdometrySlip, SlamErrorConfig
from .sim_backend import SimBackend, SimBackendConfig

TRUTH_KEY = Keys().relative(Keys().sim_truth)  # the wire contract's key, relative to {prefix}/{robot}
GEOMETRIES = ("sim", "mast3r", "rgbd")
LABELS = ("sim", "efficientvit")


class PerceptionSettings(NodeSettings):
    SERVICE: ClassVar[str] = "perception"

    geometry: str = Field("sim", description="sim | mast3r | rgbd")
    labels: str = Field("sim", description="sim | efficientvit")
    publish: Literal["keyframe", "frame", "updates"] = "keyframe"
    """keyframe: the frame with its keyframe's fused points; frame: the frame's own points; updates: the keyframe
    map-update protocol."""
    frame_depth: Literal["float16", "float32", "points"] = "float16"
    """How a frame with intrinsics crosses the wire: depth along the pixel rays (float16: ≤ 1 mm of
    rounding below 4 m; float32) + intrinsics, or HxWx3 float32 points (for receivers older than
    ``PerceptionFrame.depth``). Frames without intrinsics (mast3r) always carry points."""
    pixel_stride: int = Field(2, ge=1, le=16)
    """Frames carry every n-th pixel of the image in each direction: the mapping's ``pixel_stride``,
    applied at the source. A backend's frame already that small (sim: the simulator's
    ``truth_stride``) is sent as it is."""
    truth_key: str = TRUTH_KEY
    """Where the simulator's ground-truth frames come from (geometry sim), relative to {prefix}/{robot}/."""
    pair_timeout_s: float = Field(0.5, gt=0)
    """How long an image waits for its companion of the same stamp (ground truth or depth) before it is dropped."""
    seed: int = 0
    """Seed of the sim backend's degradation, so that a run is reproducible."""
    # degradation of the sim backend (see degrade.DegradationConfig)
    noise_a: float = Field(0.005, ge=0)
    """sim: depth noise sigma(z) = noise_a + noise_b z^2, constant term (m)."""
    noise_b: float = Field(0.004, ge=0)
    """sim: depth noise sigma(z) = noise_a + noise_b z^2, quadratic term (1/m)."""
    c_gain: float = Field(CERTAIN_CONFIDENCE - 1.0, ge=0)
    """sim: confidence 1 + c_gain cos(incidence) exp(-z / z_scale) of a valid pixel."""
    z_scale: float = Field(4.0, gt=0)
    """sim: range (m) over which the confidence decays, exp(-z / z_scale)."""
    boundary_px: int = Field(2, ge=0, le=50)
    """sim: pixels this close to a label edge may take a neighbour's label (p_boundary)."""
    p_boundary: float = Field(0.3, ge=0, le=1)
    """sim: probability that a pixel near a label edge takes a neighbour's label."""
    p_confuse: float = Field(0.05, ge=0, le=1)
    """sim: per frame and object class, probability of relabelling part of it as a plausible confusion."""
    p_salt: float = Field(0.001, ge=0, le=1)
    """sim: probability of a random label on any pixel (salt noise)."""
    drift_t: float = Field(0.0, ge=0)
    """sim: pose drift, std (m) per frame of the translation random walk; 0 = no drift."""
    drift_yaw: float = Field(0.0, ge=0)
    """sim: pose drift, std (rad) per frame of the yaw random walk; 0 = no drift."""
    correct_every: int = Field(0, ge=0, description="sim: a loop closure every n keyframes re-poses them (0: never)")
    slam_scale: float = Field(1.0, gt=0)
    """sim: SLAM's scale at the first image (its world is the true one scaled about the first camera); 1: metric."""
    scale_drift: float = Field(0.0, ge=0)
    """sim: SLAM's scale drift, σ of a random walk of log scale per √m of travel; 0 = none."""
    yaw_drift: float = Field(0.0, ge=0)
    """sim: SLAM's heading drift, σ (rad) of a random walk per √m of travel; 0 = none."""
    odom_slip: float = Field(0.0, ge=0)
    """sim: the odometry perception aligns to overstates travel by this fraction (wheel slip); 0 = none."""
    align: bool | None = None
    """Estimate SLAM's world → odometry similarity online (camera positions against odometry, Umeyama;
    the floor plane before moving), publish frames in the odometry frame and the estimate on
    perception/alignment. None: on for mast3r, off for sim and rgbd (metric worlds already)."""
    align_window_m: float = Field(1.5, gt=0)
    """align: the odometry path length (m) of camera pairs the estimate is fitted over."""
    align_converged_sigma: float = Field(0.01, gt=0)
    """align: the scale's relative standard deviation below which the estimate is converged."""
    update_every: int = Field(5, ge=1, description="re-send a refined keyframe every n tracked frames")
    confidence_threshold: float | None = Field(None, ge=0, description="pixels whose average confidence is "
                                               "below are sent with confidence 0; None: the backend's default "
                                               "(mast3r 1.5, as MASt3R-SLAM; sim and rgbd 0)")
    # keyframes
    kf_min_overlap: float = Field(0.6, ge=0, le=1)
    """A new keyframe starts when less than this fraction of the keyframe's pixels is matched in the frame."""
    kf_max_translation: float = Field(1.0, gt=0)
    """A new keyframe starts when the camera moved farther than this (m) from the keyframe."""
    kf_max_rotation_deg: float = Field(30.0, gt=0)
    """A new keyframe starts when the camera turned more than this (degrees) from the keyframe."""
    q_conf: float = Field(1.5, ge=0)
    """Match quality a pixel needs to be fused into its keyframe (MASt3R-SLAM's Q_conf)."""
    # GPU backends
    efficientvit_checkpoint: str | None = None
    """labels efficientvit: local path of the segmentation checkpoint (never downloaded at run time)."""
    efficientvit_model: str = "efficientvit-seg-l2-ade20k"  # the authors' model
    """labels efficientvit: model name of the checkpoint (an ADE20K segmentation model)."""
    device: str = "cpu"
    """Torch device of the EfficientViT labeller, e.g. cpu or cuda:0."""
    mast3r_checkpoints: str = "checkpoints"
    """geometry mast3r: folder holding the MASt3R checkpoint files."""
    mast3r_config: str | None = Field(None, description="None: config/base.yaml of the installed checkout")
    mast3r_subsample: int = Field(10, ge=1, description="keep every n-th image (the authors' base_subsample10)")
    mast3r_device: str = "cuda:0"
    """Torch device of MASt3R-SLAM (it wants CUDA)."""
    # rgbd: depth camera + odometry
    depth_key: str = "camera/depth"
    """geometry rgbd: key of the depth images paired with the camera's, relative to {prefix}/{robot}/."""
    camera_position: tuple[float, float, float] = LIMO.camera.position
    """geometry rgbd, mast3r and align: camera position (m) in the robot's base frame, x forward, y left, z up
    (default: the platform description's camera mount, ``protocol.platforms.LIMO.camera``)."""
    camera_rpy_deg: tuple[float, float, float] = LIMO.camera.rpy_deg
    """geometry rgbd, mast3r and align: camera roll, pitch, yaw (degrees) in the robot's base frame."""
    rgbd_label: str = Field("wall", description="the ADE20K class of every pixel when labels are not from a network")
    rgbd_max_depth: float = Field(6.0, gt=0)
    """geometry rgbd: depth beyond this (m) is dropped as invalid."""

    @field_validator("geometry", "labels")
    @classmethod
    def _backend(cls, v: str, info: ValidationInfo) -> str:
        known = GEOMETRIES if info.field_name == "geometry" else LABELS
        if v not in known:
            raise ValueError(f"unknown {info.field_name} backend {v!r}; known: {', '.join(known)}")
        return v

    @field_validator("rgbd_label")
    @classmethod
    def _rgbd_label(cls, v: str) -> str:
        try:
            ade20k.index(v)
        except KeyError as exc:
            raise ValueError(exc.args[0]) from None
        return v

    def camera_mount(self) -> CameraMount:
        """The calibrated extrinsic (``camera_position``, ``camera_rpy_deg``), measured as well as the
        platform's (``LIMO.camera.height_sigma``)."""
        return CameraMount(position=self.camera_position, rpy_deg=self.camera_rpy_deg,
                           height_sigma=LIMO.camera.height_sigma)


def decode_image(image: Image) -> Image:
    """An ``rgb8`` image; JPEG is decoded with Pillow (a matplotlib dependency). The header and the
    intrinsics (``Image.intrinsics``, a calibrated camera's) stay with the pixels."""
    if image.encoding == "rgb8":
        return image
    from PIL import Image as PILImage

    try:
        rgb = np.asarray(PILImage.open(io.BytesIO(image.data)).convert("RGB"))
    except (OSError, SyntaxError) as exc:  # Pillow's UnidentifiedImageError is an OSError
        raise ValueError(f"undecodable JPEG: {exc}") from exc
    if rgb.shape[:2] != (image.height, image.width):
        raise ValueError(f"JPEG is {rgb.shape[1]}x{rgb.shape[0]}, the header says {image.width}x{image.height}")
    return Image(header=image.header, encoding="rgb8", width=image.width, height=image.height, data=rgb,
                 intrinsics=image.intrinsics)


def build_backend(s: PerceptionSettings) -> PerceptionBackend:
    if s.geometry not in GEOMETRIES:  # settings validate this; a model_construct()ed object may not
        raise MissingBackend(f"unknown geometry backend {s.geometry!r}; known: {', '.join(GEOMETRIES)}")
    labeller: Labeller | None = None
    if s.labels == "efficientvit":
        from .efficientvit_backend import EfficientVitLabeller

        labeller = EfficientVitLabeller(s.efficientvit_checkpoint, s.efficientvit_model, s.device)
    if s.geometry == "mast3r":
        from .mast3r_backend import C_CONF, Mast3rBackend, SlamParams

        if labeller is None:
            raise MissingBackend("geometry=mast3r needs labels=efficientvit (a real camera has no ground truth)")
        from .rgbd_backend import Odometry

        c_conf = C_CONF if s.confidence_threshold is None else s.confidence_threshold
        odometry, T_BC = Odometry(), T_base_camera(s.camera_mount())

        def anchor(stamp_ns: int) -> np.ndarray:
            # SLAM's world is its first camera: put it where odometry says the camera was (the
            # base at the origin without odometry).
            try:
                return odometry.pose_at(stamp_ns) @ T_BC
            except ValueError:
                return T_BC

        params = SlamParams(s.mast3r_device, s.q_conf, c_conf, s.update_every)
        backend = Mast3rBackend(labeller, s.mast3r_checkpoints, s.mast3r_config, params,
                                overrides={"dataset": {"subsample": s.mast3r_subsample}}, anchor=anchor)
        backend.odometry = odometry  # type: ignore[attr-defined]  # fed from the state key by setup()
        return backend
    if s.geometry == "rgbd":
        from .rgbd_backend import RgbdBackend, RgbdConfig

        return RgbdBackend(RgbdConfig(s.camera_mount(), ade20k.index(s.rgbd_label), max_depth=s.rgbd_max_depth),
                           labeller)
    deg = DegradationConfig(s.noise_a, s.noise_b, s.c_gain, s.z_scale, s.boundary_px, s.p_boundary, s.p_confuse,
                            s.p_salt, s.drift_t, s.drift_yaw)
    return SimBackend(SimBackendConfig(deg, s.publish, s.kf_min_overlap, s.kf_max_translation, s.kf_max_rotation_deg,
                                       s.q_conf, seed=s.seed, correct_every=s.correct_every,
                                       update_every=s.update_every,
                                       c_conf=s.confidence_threshold or 0.0,
                                       slam=SlamErrorConfig(s.slam_scale, s.scale_drift, s.yaw_drift, s.odom_slip)),
                      labeller)


def build_aligner(s: PerceptionSettings) -> FrameAligner | None:
    """The SLAM → odometry aligner the settings ask for (``align``), or None."""
    if not (s.align if s.align is not None else s.geometry == "mast3r"):
        return None
    slip = OdometrySlip(s.odom_slip) if s.geometry == "sim" and s.odom_slip > 0 else None
    mount = s.camera_mount()
    return FrameAligner(T_base_camera(mount), mount.height_sigma,
                        AlignerConfig(window_m=s.align_window_m, converged_sigma=s.align_converged_sigma),
                        odometry_view=slip)


class Perception:
    """Pairs images with truth, runs the backend, publishes its frames."""

    def __init__(self, node: Node, s: PerceptionSettings, backend: PerceptionBackend,
                 aligner: FrameAligner | None = None):
        self.node, self.s, self.backend = node, s, backend
        self.aligner = aligner  # SLAM's world → odometry (``alignment``), None: the backend's world is metric
        self.truths: OrderedDict[int, PerceptionFrame | DepthImage] = OrderedDict()
        self.paired = backend.needs_truth or getattr(backend, "needs_depth", False)
        self.companion_key = s.truth_key if backend.needs_truth else s.depth_key
        self.pending: tuple[Image, float] | None = None
        self.rejected = 0
        self.unpaired = 0

    def on_image(self, image: Image) -> None:
        if not self.paired:
            self._run(image, None)
            return
        truth = self.truths.pop(image.header.stamp_ns, None)
        if truth is not None:
            self._run(image, truth)
            return
        if self.pending is not None:
            self.unpaired += 1
        self.pending = (image, time.monotonic())

    def on_truth(self, truth: PerceptionFrame | DepthImage) -> None:
        """The image's companion: the simulator's truth (sim) or the depth image (rgbd)."""
        if self.pending is not None and self.pending[0].header.stamp_ns == truth.header.stamp_ns:
            image, _ = self.pending
            self.pending = None
            self._run(image, truth)
            return
        self.truths[truth.header.stamp_ns] = truth
        while len(self.truths) > 8:
            self.truths.popitem(last=False)

    def expire(self) -> None:
        if self.pending is not None and time.monotonic() - self.pending[1] > self.s.pair_timeout_s:
            self.pending = None
            self.unpaired += 1
            self.node.stats["unpaired_images"] = self.unpaired
            self.node.ratelog(logging.WARNING, "unpaired", f"an image got no {self.companion_key} in time (is "
                              "the simulator or the camera driver publishing it? simulator: publish_depth=true)")

    def _compact(self, frame: PerceptionFrame, image: Image) -> PerceptionFrame:
        """The frame at the mapping's pixel stride, as depth (``compact``)."""
        have = frame_stride((image.height, image.width), frame.pixels) or 1
        return compact(frame, self.s.frame_depth, max(1, self.s.pixel_stride // have))

    def _run(self, image: Image, truth: PerceptionFrame | DepthImage | None) -> None:
        try:
            image = decode_image(image)
            if isinstance(truth, PerceptionFrame) and frame_stride((image.height, image.width), truth.pixels) is None:
                raise ValueError(f"truth is {truth.pixels[1]}x{truth.pixels[0]}, the image "
                                 f"{image.width}x{image.height} (nor every n-th pixel of it)")
            t0 = time.perf_counter()
            if image.header.stamp_ns > 0:  # image stamp → processing starts: transport, pairing, decode
                self.node.stats["start_age_ms"] = (time.time_ns() - image.header.stamp_ns) / 1e6
            frames = self.backend.process(image, truth, image.header.stamp_ns)  # type: ignore[arg-type]
            self.node.stats["process_ms"] = (time.perf_counter() - t0) * 1e3
        except (ValueError, OSError) as exc:
            self.rejected += 1
            self.node.stats["frames_rejected"] = self.rejected
            self.node.ratelog(logging.WARNING, "reject", f"could not process a frame: {exc}")
            return
        if self.aligner is not None:
            frames = self._align(frames, image.header.stamp_ns)
        for f in frames:
            self.node.publish(self.node.keys.perception_frame, self._compact(f, image))
        if isinstance(self.backend, SimBackend):
            self.node.stats["keyframes"] = self.backend.n_keyframes
            m = self.backend.last_matches
            self.node.stats["overlap"] = m.overlap if m is not None else 1.0


    def _align(self, frames: list[PerceptionFrame], stamp_ns: int) -> list[PerceptionFrame]:
        """The frames in the odometry frame, and the estimate on ``perception/alignment``; none
        while no odometry has posed a camera yet (counted in ``unaligned``)."""
        assert self.aligner is not None
        try:
            out = self.aligner.align(frames, stamp_ns)
        except ValueError as exc:
            out = []
            self.node.ratelog(logging.WARNING, "align", f"could not align a frame: {exc}")
        if frames and not out:
            self.node.stats["unaligned"] = self.node.stats.get("unaligned", 0) + len(frames)
            self.node.ratelog(logging.WARNING, "unaligned", f"frames held back: no odometry on "
                              f"{self.node.keys.state} near the image to scale SLAM's world by")
        est = self.aligner.last
        if est is not None:
            self.node.publish(self.node.keys.alignment, est.message(stamp_ns))
            self.node.stats["align_scale"] = est.similarity.scale
            self.node.stats["align_sigma"] = est.scale_sigma
            self.node.stats["align_residual"] = est.residual
        return out


def setup(node: Node, s: PerceptionSettings) -> Perception:
    try:
        backend = build_backend(s)
    except MissingBackend as exc:
        raise ServiceUnavailable(f"perception backend unavailable: {exc}") from exc
    if isinstance(backend, SimBackend):
        backend.warm_up()  # compile before the first frame, not on it
    aligner = build_aligner(s)
    p = Perception(node, s, backend, aligner)
    node.subscribe(node.keys.camera_image, Image, p.on_image, queue="latest")
    if aligner is not None:
        node.subscribe(node.keys.state, RobotState, aligner.odometry.on_state, queue="fifo", maxlen=64)
    if backend.needs_truth:
        node.subscribe(node.keys.key(s.truth_key), PerceptionFrame, p.on_truth, queue="fifo", maxlen=4)
        node.every(0.1, p.expire)
    if hasattr(backend, "odometry") and not getattr(backend, "needs_depth", False):  # mast3r: the map anchor
        node.subscribe(node.keys.state, RobotState, backend.odometry.on_state, queue="fifo", maxlen=64)
    if getattr(backend, "needs_depth", False):
        node.subscribe(node.keys.key(s.depth_key), DepthImage, p.on_truth, queue="fifo", maxlen=4)
        node.subscribe(node.keys.state, RobotState, backend.on_state, queue="fifo", maxlen=64)  # type: ignore[attr-defined]
        node.every(0.1, p.expire)
    node.log.info("perception: geometry %s, labels %s, publishing %s", s.geometry, s.labels, s.publish)
    return p


SERVICE = ServiceSpec("perception", PerceptionSettings, setup)
