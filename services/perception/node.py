"""The perception node: ``camera/image`` (+ ``sim/truth`` for the sim backend) → ``perception/frame``.

Settings choose the geometry (``sim`` | ``mast3r``) and the labels (``sim`` | ``efficientvit``).
With ``geometry = sim`` each image is paired with the simulator's ground-truth frame carrying
the same ``header.stamp_ns`` (key ``{prefix}/{robot}/sim/truth``, see the simulator node);
images wait at most ``pair_timeout_s`` for their truth. Output frames keep the image's stamp.
"""

from __future__ import annotations

import io
import logging
import time
from collections import OrderedDict
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from riskfield.protocol import Image, PerceptionFrame

from ..runtime.node import Node
from ..runtime.service import ServiceSpec, ServiceUnavailable
from ..runtime.settings import NodeSettings
from .backend import Labeller, MissingBackend, PerceptionBackend
from .degrade import DegradationConfig
from .sim_backend import SimBackend, SimBackendConfig

TRUTH_KEY = "sim/truth"


class PerceptionSettings(NodeSettings):
    SERVICE: ClassVar[str] = "perception"

    geometry: Literal["sim", "mast3r"] = "sim"
    labels: Literal["sim", "efficientvit"] = "sim"
    publish: Literal["keyframe", "frame"] = "keyframe"
    truth_key: str = TRUTH_KEY
    pair_timeout_s: float = Field(0.5, gt=0)
    seed: int = 0
    # degradation of the sim backend (see degrade.DegradationConfig)
    noise_a: float = Field(0.005, ge=0)
    noise_b: float = Field(0.004, ge=0)
    c_gain: float = Field(9.0, ge=0)
    z_scale: float = Field(4.0, gt=0)
    boundary_px: int = Field(2, ge=0, le=50)
    p_boundary: float = Field(0.3, ge=0, le=1)
    p_confuse: float = Field(0.05, ge=0, le=1)
    p_salt: float = Field(0.001, ge=0, le=1)
    drift_t: float = Field(0.0, ge=0)
    drift_yaw: float = Field(0.0, ge=0)
    # keyframes
    kf_min_overlap: float = Field(0.6, ge=0, le=1)
    kf_max_translation: float = Field(1.0, gt=0)
    kf_max_rotation_deg: float = Field(30.0, gt=0)
    q_conf: float = Field(1.5, ge=0)
    # GPU backends
    efficientvit_checkpoint: str | None = None
    efficientvit_model: str = "efficientvit-seg-l1-ade20k"
    device: str = "cpu"
    mast3r_checkpoints: str = "checkpoints"
    mast3r_config: str | None = None
    mast3r_device: str = "cuda:0"


def decode_image(image: Image) -> Image:
    """An ``rgb8`` image; JPEG is decoded with Pillow (a matplotlib dependency)."""
    if image.encoding == "rgb8":
        return image
    from PIL import Image as PILImage

    rgb = np.asarray(PILImage.open(io.BytesIO(image.data)).convert("RGB"))
    if rgb.shape[:2] != (image.height, image.width):
        raise ValueError(f"JPEG is {rgb.shape[1]}x{rgb.shape[0]}, the header says {image.width}x{image.height}")
    return Image(header=image.header, encoding="rgb8", width=image.width, height=image.height, data=rgb)


def build_backend(s: PerceptionSettings) -> PerceptionBackend:
    labeller: Labeller | None = None
    if s.labels == "efficientvit":
        from .efficientvit_backend import EfficientVitLabeller

        labeller = EfficientVitLabeller(s.efficientvit_checkpoint, s.efficientvit_model, s.device)
    if s.geometry == "mast3r":
        from .mast3r_backend import Mast3rBackend

        if labeller is None:
            raise MissingBackend("geometry=mast3r needs labels=efficientvit (a real camera has no ground truth)")
        return Mast3rBackend(labeller, s.mast3r_checkpoints, s.mast3r_config, s.mast3r_device, s.q_conf)
    deg = DegradationConfig(s.noise_a, s.noise_b, s.c_gain, s.z_scale, s.boundary_px, s.p_boundary, s.p_confuse,
                            s.p_salt, s.drift_t, s.drift_yaw)
    return SimBackend(SimBackendConfig(deg, s.publish, s.kf_min_overlap, s.kf_max_translation, s.kf_max_rotation_deg,
                                       s.q_conf, seed=s.seed), labeller)


class Perception:
    """Pairs images with truth, runs the backend, publishes its frames."""

    def __init__(self, node: Node, s: PerceptionSettings, backend: PerceptionBackend):
        self.node, self.s, self.backend = node, s, backend
        self.truths: OrderedDict[int, PerceptionFrame] = OrderedDict()
        self.pending: tuple[Image, float] | None = None
        self.rejected = 0
        self.unpaired = 0

    def on_image(self, image: Image) -> None:
        if not self.backend.needs_truth:
            self._run(image, None)
            return
        truth = self.truths.pop(image.header.stamp_ns, None)
        if truth is not None:
            self._run(image, truth)
            return
        if self.pending is not None:
            self.unpaired += 1
        self.pending = (image, time.monotonic())

    def on_truth(self, truth: PerceptionFrame) -> None:
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
            self.node.ratelog(logging.WARNING, "unpaired", "an image got no ground-truth frame in time (is the "
                              f"simulator publishing {self.s.truth_key}?)")

    def _run(self, image: Image, truth: PerceptionFrame | None) -> None:
        try:
            image = decode_image(image)
            if truth is not None and truth.points.shape[:2] != (image.height, image.width):
                raise ValueError(f"truth is {truth.points.shape[1]}x{truth.points.shape[0]}, "
                                 f"the image {image.width}x{image.height}")
            t0 = time.perf_counter()
            frames = self.backend.process(image, truth, image.header.stamp_ns)
            self.node.stats["process_ms"] = (time.perf_counter() - t0) * 1e3
        except (ValueError, OSError) as exc:
            self.rejected += 1
            self.node.stats["frames_rejected"] = self.rejected
            self.node.ratelog(logging.WARNING, "reject", f"could not process a frame: {exc}")
            return
        for f in frames:
            self.node.publish(self.node.keys.perception_frame, f)
        if isinstance(self.backend, SimBackend):
            self.node.stats["keyframes"] = self.backend.n_keyframes
            m = self.backend.last_matches
            self.node.stats["overlap"] = m.overlap if m is not None else 1.0


def setup(node: Node, s: PerceptionSettings) -> Perception:
    try:
        backend = build_backend(s)
    except MissingBackend as exc:
        raise ServiceUnavailable(f"perception backend unavailable: {exc}") from exc
    p = Perception(node, s, backend)
    node.subscribe(node.keys.camera_image, Image, p.on_image, queue="latest")
    if backend.needs_truth:
        node.subscribe(node.keys.key(s.truth_key), PerceptionFrame, p.on_truth, queue="fifo", maxlen=4)
        node.every(0.1, p.expire)
    node.log.info("perception: geometry %s, labels %s, publishing %s", s.geometry, s.labels, s.publish)
    return p


SERVICE = ServiceSpec("perception", PerceptionSettings, setup)
