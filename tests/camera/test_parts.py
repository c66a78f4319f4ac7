"""The camera's small parts: JPEG headers, the one-frame slot, capture stamps, pixel conversions."""

from __future__ import annotations

import io
import threading

import numpy as np
import pytest
from camera.media import pillow_jpeg, strip_huffman_tables
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image as PILImage

from riskfield.protocol.jpeg import jpeg_info
from riskfield.services.camera.capture import Pixels, RawFrame, source_kind
from riskfield.services.camera.latest import LatestSlot, PlaybackClock, driver_stamp_to_wall


@given(st.integers(1, 300), st.integers(1, 300), st.booleans())
def test_jpeg_size_and_tables_from_the_header(width, height, progressive):
    jpeg = pillow_jpeg(np.full((height, width, 3), 90, np.uint8), progressive=progressive)
    info = jpeg_info(jpeg)
    assert (info.width, info.height, info.has_huffman_tables) == (width, height, True)
    bare = jpeg_info(strip_huffman_tables(jpeg))
    assert (bare.width, bare.height, bare.has_huffman_tables) == (width, height, False)


@given(st.binary(max_size=64))
def test_garbage_is_not_a_jpeg(data):
    try:
        info = jpeg_info(data)
    except ValueError:
        return
    assert info.width > 0 and info.height > 0  # only a real SOF header gives a size


def test_the_slot_keeps_the_newest_and_counts_what_it_overwrote():
    slot: LatestSlot[int] = LatestSlot()
    assert slot.take() is None
    assert slot.put(1) is True  # empty: the taker must be woken
    assert slot.put(2) is False and slot.put(3) is False
    assert slot.take() == 3 and slot.take() is None
    assert (slot.put_count, slot.dropped) == (3, 2)


def test_the_slot_under_a_racing_producer_never_reorders_or_loses_count():
    slot: LatestSlot[int] = LatestSlot()
    taken: list[int] = []
    done = threading.Event()

    def produce() -> None:
        for i in range(20000):
            slot.put(i)
        done.set()

    t = threading.Thread(target=produce)
    t.start()
    while True:
        finished = done.is_set()  # read before the take: a put after it is still taken next round
        item = slot.take()
        if item is not None:
            taken.append(item)
        elif finished:
            break
    t.join()
    assert taken == sorted(set(taken)) and taken[-1] == 19999
    assert len(taken) + slot.dropped == slot.put_count == 20000


WALL = st.integers(1_600_000_000 * 10**9, 2_000_000_000 * 10**9)
MONO = st.integers(10**9, 10**15)  # up to ~30 years of uptime, far below any wall-clock time
AGE = st.integers(-900_000_000, 9_000_000_000)  # a frame up to 9 s old, or stamped a little ahead


@given(WALL, MONO, AGE)
def test_monotonic_driver_stamps_move_to_the_wall_clock(wall, mono, age):
    assert driver_stamp_to_wall(mono - age, wall, mono) == wall - age


@given(WALL, MONO, AGE)
def test_wall_clock_driver_stamps_are_kept(wall, mono, age):
    assert driver_stamp_to_wall(wall - age, wall, mono) == wall - age


@given(WALL, MONO, st.integers(11 * 10**9, 10**12))
def test_stamps_on_no_known_clock_are_refused(wall, mono, off):
    assert driver_stamp_to_wall(mono - off, wall, mono) is None
    assert driver_stamp_to_wall(wall + off, wall, mono) is None


def test_playback_clock_continues_across_loops():
    clock = PlaybackClock(wall0_ns=10**18, mono0_ns=5 * 10**9)
    assert clock.wall(50_000_000) == 10**18 + 50_000_000
    clock.offset_ns += 1_000_000_000
    assert clock.wall(0) == 10**18 + 10**9 and clock.due_mono(0) == 6 * 10**9


def test_source_kinds(tmp_path):
    assert source_kind("/dev/video3") == "v4l2"
    assert source_kind("/dev/null") == "v4l2"  # any character device is read as V4L2
    assert source_kind(str(tmp_path)) == "folder"
    assert source_kind(str(tmp_path / "clip.mkv")) == "file"


def test_yuyv_frames_convert_to_rgb():
    # YUYV (BT.601 limited range): Y=235 with neutral chroma is white, Y=16 black.
    yuyv = np.zeros((2, 4, 2), np.uint8)
    yuyv[..., 1] = 128
    yuyv[0, :, 0], yuyv[1, :, 0] = 235, 16
    rgb = Pixels().rgb(RawFrame("yuyv", yuyv.tobytes(), 4, 2))
    assert rgb.shape == (2, 4, 3)
    assert np.all(rgb[0] >= 250) and np.all(rgb[1] <= 5)
    with pytest.raises(ValueError, match="YUYV frame"):
        Pixels().rgb(RawFrame("yuyv", b"\0" * 10, 4, 2))


@pytest.mark.parametrize(("width", "height"), [(64, 48), (33, 17), (640, 480)])
def test_jpeg_encode_and_decode_round_trip(width, height):
    y, x = np.mgrid[0:height, 0:width]
    rgb = np.stack([x * 255 // max(width - 1, 1), y * 255 // max(height - 1, 1), np.full_like(x, 128)],
                   axis=-1).astype(np.uint8)
    pixels = Pixels(jpeg_quality=95)
    jpeg = pixels.jpeg(rgb)
    assert jpeg_info(jpeg).has_huffman_tables and (jpeg_info(jpeg).width, jpeg_info(jpeg).height) == (width, height)
    assert pixels.jpeg(rgb) != b""  # a second frame through the same encoder
    back = pixels.rgb(RawFrame("jpeg", jpeg, width, height))
    tol = 4 if width >= 64 else 8  # 4:2:0 chroma on a 17-row image whose colour changes 15 levels a row
    assert np.abs(back.astype(int) - rgb).mean() < tol
    # Pillow (what perception decodes with) reads the node's JPEGs as well.
    assert np.abs(np.asarray(PILImage.open(io.BytesIO(jpeg))).astype(int) - rgb).mean() < tol


def test_a_uvc_style_jpeg_without_tables_decodes():
    rgb = np.zeros((32, 48, 3), np.uint8)
    rgb[:, 24:] = 200
    bare = strip_huffman_tables(pillow_jpeg(rgb, quality=95))
    back = Pixels().rgb(RawFrame("jpeg", bare, 48, 32))
    assert np.abs(back.astype(int) - rgb).mean() < 4
    with pytest.raises(ValueError, match="JPEG"):
        Pixels().rgb(RawFrame("jpeg", b"\xff\xd8\xff\xe0 not really", 48, 32))
