"""Test media the camera tests play: real encoded videos and image folders whose frames carry their
index in their pixels (8 blocks, one bit each, large enough to survive lossy compression)."""

from __future__ import annotations

import io
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
from PIL import Image as PILImage

BITS = 8


def frame_pixels(index: int, width: int = 96, height: int = 64) -> np.ndarray:
    """An RGB frame showing ``index`` as 8 black/white blocks across its top half, over a gradient."""
    rgb = np.zeros((height, width, 3), np.uint8)
    rgb[height // 2:] = np.linspace(40, 200, width, dtype=np.uint8)[None, :, None]
    bw = width // BITS
    for b in range(BITS):
        if index >> b & 1:
            rgb[: height // 2, b * bw:(b + 1) * bw] = 255
    return rgb


def read_index(rgb: np.ndarray) -> int:
    """The index ``frame_pixels`` drew (block centres, thresholded at mid-grey)."""
    height, width = rgb.shape[:2]
    bw = width // BITS
    y0, y1 = height // 8, height // 2 - height // 8
    value = 0
    for b in range(BITS):
        block = rgb[y0:y1, b * bw + bw // 4:(b + 1) * bw - bw // 4]
        if block.mean() > 128:
            value |= 1 << b
    return value


def write_video(path: Path, n: int, fps: int, width: int = 96, height: int = 64, codec: str = "mpeg4") -> Path:
    """A real encoded video (``codec`` in the container ``path`` names) of ``n`` indexed frames."""
    with av.open(str(path), "w") as out:
        stream = out.add_stream(codec, rate=Fraction(fps))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.codec_context.options = {"qmin": "2", "qmax": "2"}  # near-lossless: the bits stay readable
        for i in range(n):
            frame = av.VideoFrame.from_ndarray(frame_pixels(i, width, height), format="rgb24")
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


def pillow_jpeg(rgb: np.ndarray, **kw: object) -> bytes:
    buf = io.BytesIO()
    PILImage.fromarray(rgb).save(buf, format="JPEG", **kw)
    return buf.getvalue()


def strip_huffman_tables(jpeg: bytes) -> bytes:
    """What many UVC cameras send: the JPEG without its DHT segments (the standard tables implied)."""
    out, i = bytearray(jpeg[:2]), 2
    while i < len(jpeg):
        marker, length = jpeg[i + 1], (jpeg[i + 2] << 8) | jpeg[i + 3]
        if marker == 0xDA:
            out += jpeg[i:]
            break
        if marker != 0xC4:
            out += jpeg[i:i + 2 + length]
        i += 2 + length
    return bytes(out)
