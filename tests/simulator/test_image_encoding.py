"""camera/image's two encodings: JPEG at the source by default (what crosses a robot's link), raw
``rgb8`` on request; perception decodes either to the same pixels it would have had."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from riskfield.protocol import Image, decode, encode
from riskfield.services.perception.node import decode_image
from riskfield.services.simulator.node import SimulatorSettings, jpeg_bytes
from riskfield.services.simulator.scenario import load_scenario
from riskfield.services.simulator.world import World
from riskfield.testing import Collector, ServiceProcess, client_session, wait_alive

SCENARIO = str(Path(__file__).parent / "data" / "two_boxes.yaml")


def test_jpeg_is_the_default_encoding() -> None:
    assert SimulatorSettings().image_encoding == "jpeg"


@settings(max_examples=25, deadline=None)
@given(h=st.integers(8, 64), w=st.integers(8, 64), colour=st.tuples(*[st.integers(0, 255)] * 3),
       quality=st.integers(50, 100))
def test_jpeg_round_trip_through_the_wire_keeps_size_and_flat_colour(h: int, w: int, colour: tuple, quality: int
                                                                     ) -> None:
    rgb = np.empty((h, w, 3), np.uint8)
    rgb[:] = colour
    msg = Image(encoding="jpeg", width=w, height=h, data=jpeg_bytes(rgb, quality))
    out = decode_image(decode(encode(msg), Image))
    assert out.encoding == "rgb8" and out.data.shape == (h, w, 3)
    assert np.abs(out.data.astype(int) - rgb).max() <= 8  # chroma subsampling and rounding only


def test_a_rendered_frame_is_small_and_close_as_jpeg() -> None:
    rgb = World(load_scenario("navigation")).render().rgb
    data = jpeg_bytes(rgb, SimulatorSettings().jpeg_quality)
    back = decode_image(Image(encoding="jpeg", width=rgb.shape[1], height=rgb.shape[0], data=data)).data
    assert len(data) < rgb.nbytes / 10
    assert np.abs(back.astype(float) - rgb).mean() < 3.0


def test_rgb8_on_request(router_endpoint: str) -> None:
    robot = "t_sim_rgb8"
    args = ["--robot", robot, "--set", f"scenario={SCENARIO}", "--set", "image_encoding=rgb8",
            "--set", "publish_truth=false"]
    with ServiceProcess("simulator", router_endpoint, args) as sim, client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{robot}/alive/simulator"), sim.output
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        img = images.wait(1, 20)[-1]
        assert img.encoding == "rgb8" and img.data.shape == (96, 128, 3)
        images.close()
