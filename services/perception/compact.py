"""The compact perception frame: what mapping uses, at the size it uses it.

A frame with pinhole intrinsics is sent as depth (z along each pixel's ray) instead of three
float32 per pixel, and at the mapping's pixel stride (every n-th pixel in each direction, the
intrinsics scaled by 1/n: ``PinholeCamera.strided``). The receiver rebuilds the points with
``PerceptionFrame.pointmap``. What is lost:

* float16 rounding of z: half a unit in the last place, ≤ 0.98 mm below 4 m, ≤ 1.95 mm below 8 m;
* a point off its pixel's ray (the ``sim`` backend's fused keyframe points sit where a trusted
  match put them, up to half a pixel off) comes back on the ray at the same z: ≤ half a pixel's
  diagonal footprint, √2·z/(2 fx) (1.1 cm at 4 m for the default 512×384 camera, fx 256; measured
  at 1–4 m: median 0.8 mm, max 11.7 mm) — a fifth of a 5 cm voxel, below the depth noise there;
* the pixels between the stride's, which the mapping does not integrate (``pixel_stride``).

``tests/perception/test_compact.py`` bounds the first two; ``riskfield bench latency --path replay``
measures them against the full-size frames of the ``sim`` backend (``experiments.replay.record``).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from riskfield.protocol import PerceptionFrame

#: Largest z kept in float16 (its largest finite value is 65504); farther is "no return".
F16_MAX_DEPTH = 6.0e4

DepthFormat = Literal["float16", "float32", "points"]


def frame_stride(image_hw: tuple[int, int], frame_hw: tuple[int, int]) -> int | None:
    """The n for which a frame of ``frame_hw`` holds every n-th pixel of an image of ``image_hw``
    (pixels 0, n, 2n, …), or None when there is none."""
    (H, W), (h, w) = image_hw, frame_hw
    if h <= 0 or w <= 0:
        return None
    n = max(1, round(W / w))
    return n if (-(-H // n), -(-W // n)) == (h, w) else None


def compact(frame: PerceptionFrame, fmt: DepthFormat = "float16", stride: int = 1) -> PerceptionFrame:
    """``frame`` as depth + intrinsics (``fmt``) at every ``stride``-th pixel; unchanged when it has
    no intrinsics (its pixels are not a pinhole's), is already depth, or ``fmt`` is ``points`` and
    ``stride`` 1. A point at z ≤ 0 or beyond float16's range is sent as no return (confidence 0)."""
    if frame.intrinsics is None or frame.points is None or (fmt == "points" and stride == 1):
        return frame
    n = int(stride)
    fx, fy, cx, cy = frame.intrinsics
    K = (fx / n, fy / n, cx / n, cy / n)
    points = frame.points[::n, ::n]
    conf, labels = frame.confidence[::n, ::n], frame.labels[::n, ::n]
    common = dict(header=frame.header, T_WC=frame.T_WC, labels=np.ascontiguousarray(labels),
                  keyframe_id=frame.keyframe_id, kind=frame.kind, intrinsics=K)
    if fmt == "points":
        return PerceptionFrame(points=np.ascontiguousarray(points), confidence=np.ascontiguousarray(conf), **common)
    z = points[..., 2]
    ok = (z > 0) & (z <= F16_MAX_DEPTH)
    depth = np.where(ok, z, np.float32(0.0)).astype(np.float16 if fmt == "float16" else np.float32)
    return PerceptionFrame(depth=depth, confidence=np.where(ok, conf, np.float32(0.0)), **common)
