"""`Image` on the wire: the additive ``intrinsics`` field, and perception's decoding of both encodings."""

from __future__ import annotations

import io

import msgpack
import numpy as np
import pytest
from PIL import Image as PILImage

from riskfield.protocol import DecodeError, Image, decode, encode
from riskfield.protocol.messages import Header
from riskfield.services.camera.capture import Pixels
from riskfield.services.perception.node import decode_image

K = (120.0, 118.0, 47.5, 31.5)


def _rgb() -> np.ndarray:
    y, x = np.mgrid[0:64, 0:96]
    return np.stack([x * 2, y * 3, np.full_like(x, 128)], axis=-1).astype(np.uint8)


def test_intrinsics_travel_and_older_images_stay_valid():
    img = Image(encoding="rgb8", width=96, height=64, data=_rgb(), intrinsics=K)
    assert decode(encode(img), Image).intrinsics == K
    old = encode(Image(encoding="rgb8", width=96, height=64, data=_rgb()))
    assert decode(old, Image).intrinsics is None
    bad = msgpack.unpackb(encode(img), raw=False)
    for value in ([float("nan"), 1.0, 2.0, 3.0], [0.0, 1.0, 2.0, 3.0], [1.0, 2.0]):
        bad["intrinsics"] = value
        with pytest.raises(DecodeError, match="intrinsics"):
            decode(msgpack.packb(bad, use_bin_type=True), Image)


@pytest.mark.parametrize("source", ["camera", "pillow"])
def test_perception_decodes_rgb8_and_jpeg_keeping_stamp_and_intrinsics(source):
    rgb = _rgb()
    header = Header(stamp_ns=123_456_789, frame_id="camera", seq=7)
    as_rgb = Image(header=header, encoding="rgb8", width=96, height=64, data=rgb, intrinsics=K)
    assert decode_image(as_rgb) is as_rgb
    if source == "camera":  # what `riskfield run camera` encodes (FFmpeg's mjpeg)
        jpeg = Pixels(jpeg_quality=95).jpeg(rgb)
    else:
        buf = io.BytesIO()
        PILImage.fromarray(rgb).save(buf, format="JPEG", quality=95)
        jpeg = buf.getvalue()
    wire = decode(encode(Image(header=header, encoding="jpeg", width=96, height=64, data=jpeg, intrinsics=K)), Image)
    out = decode_image(wire)
    assert out.encoding == "rgb8" and out.data.shape == (64, 96, 3)
    assert np.abs(out.data.astype(int) - rgb).mean() < 4
    assert out.header == wire.header and out.intrinsics == K


def test_perception_refuses_jpeg_that_is_not_what_the_header_says():
    jpeg = Pixels().jpeg(_rgb())
    with pytest.raises(ValueError, match="header says"):
        decode_image(Image(encoding="jpeg", width=32, height=64, data=jpeg))
    with pytest.raises(ValueError, match="JPEG"):
        decode_image(Image(encoding="jpeg", width=96, height=64, data=b"\xff\xd8\xff\xe0garbage"))
