"""The interface every perception backend implements, and the error of a missing one.

A *geometry* backend turns images (and, in simulation, ground truth) into frames; a *labeller*
turns an RGB image into an ADE20K label map at image resolution. A geometry backend may use a
labeller for its labels (``mast3r`` always does; ``sim`` does when one is given, else it
degrades the true labels).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from riskfield.protocol import Image, PerceptionFrame


class MissingBackend(RuntimeError):
    """A backend whose framework, extension or checkpoint is not installed here."""


class Labeller(Protocol):
    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB → (H, W) uint16 ADE20K labels."""
        ...


class PerceptionBackend(Protocol):
    #: whether ``process`` needs the simulator's ground truth for each image
    needs_truth: bool

    def process(self, image: Image | None, truth: PerceptionFrame | None, stamp_ns: int) -> list[PerceptionFrame]:
        """Frames to publish for one camera image: usually one (the current keyframe or frame),
        several when keyframes were re-optimised (re-published), none while initialising."""
        ...


def image_rgb(image: Image) -> np.ndarray:
    """The (H, W, 3) uint8 array of an ``rgb8`` image (JPEG is decoded by the node's caller)."""
    if image.encoding != "rgb8":
        raise ValueError(f"image encoding {image.encoding!r}: this backend needs rgb8")
    return np.asarray(image.data)
