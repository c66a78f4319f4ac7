"""What a producer of ``Image`` ``encoding: "jpeg"`` must know of a JPEG without decoding it: its
size, and whether it is complete.

Pure (bytes in, no dependency). A camera's MJPEG frame (the camera node) or a ROS CompressedImage
(the ROS 2 bridge) goes on the wire as it is, so its width and height come from the frame header
(SOF), and it must be a JPEG any decoder reads: many UVC cameras send "MJPEG" frames without Huffman
tables (DHT), relying on the table the AVI/MJPEG convention implies; FFmpeg's decoder fills that in,
Pillow (which perception decodes with) does not. Such frames must be decoded and re-encoded first.
Marker layout: ITU-T T.81, Annex B.
"""

from __future__ import annotations

from dataclasses import dataclass

_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
_STANDALONE = {0x01, *range(0xD0, 0xD8)}  # TEM, RSTn: no length field


@dataclass(frozen=True)
class JpegInfo:
    width: int
    height: int
    has_huffman_tables: bool


def jpeg_info(data: bytes | memoryview) -> JpegInfo:
    """Width, height and whether a DHT segment precedes the first scan; ``ValueError`` when the
    bytes are not a baseline/progressive JPEG with a frame header."""
    b = bytes(data[:65536]) if len(data) > 65536 else bytes(data)
    if len(b) < 4 or b[0] != 0xFF or b[1] != 0xD8:
        raise ValueError("not a JPEG (no SOI marker)")
    i, size, dht = 2, None, False
    while i + 4 <= len(b):
        if b[i] != 0xFF:
            raise ValueError(f"corrupt JPEG: no marker at byte {i}")
        marker = b[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in _STANDALONE:
            i += 2
            continue
        length = (b[i + 2] << 8) | b[i + 3]
        if length < 2:
            raise ValueError(f"corrupt JPEG: segment length {length} at byte {i}")
        if marker == 0xC4:
            dht = True
        elif marker in _SOF:
            if i + 9 > len(b):
                break
            height, width = (b[i + 5] << 8) | b[i + 6], (b[i + 7] << 8) | b[i + 8]
            size = (width, height)
        elif marker == 0xDA:  # start of scan: tables come before it
            break
        i += 2 + length
    if size is None or size[0] <= 0 or size[1] <= 0:
        raise ValueError("JPEG without a frame header (SOF) or with a zero size")
    return JpegInfo(size[0], size[1], dht)
