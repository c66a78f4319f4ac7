"""A real V4L2 camera, where the machine has one: driver-stamped frames on `camera/image`."""

from __future__ import annotations

import glob
import time

import pytest

from riskfield.protocol import Image
from riskfield.testing import Collector, ServiceProcess, StatusWatch, client_session

DEVICES = sorted(glob.glob("/dev/video*"))


@pytest.mark.skipif(not DEVICES, reason="no V4L2 device (/dev/video*) on this machine")
@pytest.mark.parametrize("input_format", ["mjpeg", "yuyv"])
def test_a_v4l2_camera_publishes_driver_stamped_frames(router_endpoint, input_format):
    robot = f"t_cam_v4l2_{input_format}"
    with client_session(router_endpoint) as s:
        images = Collector(s, f"rf/{robot}/camera/image", Image)
        status = StatusWatch(s, f"rf/{robot}/status/camera")
        args = ["--robot", robot, "--set", f"source={DEVICES[0]}", "--set", f"input_format={input_format}",
                "--set", "status_period_s=0.2"]
        with ServiceProcess("camera", router_endpoint, args) as cam:
            try:
                msgs = images.wait(5, 30)
            except TimeoutError:
                if "cannot open V4L2 device" in cam.output or "gives" in cam.output:
                    pytest.skip(f"{DEVICES[0]} does not capture {input_format}: {cam.output.splitlines()[-1]}")
                raise
            arrived = time.time_ns()
            st = status.wait(lambda st: st.extra.get("frames_published", 0) >= 5)
            assert cam.stop() == 0, cam.output
        images.close()
        status.close()
    stamps = [m.header.stamp_ns for m in msgs[:5]]
    assert stamps == sorted(set(stamps))
    assert all(t <= arrived for t in stamps)  # captured before they arrived: not stamped in the future
    assert st.extra["stamp_fallbacks"] == 0  # every stamp is the driver's
    assert all(m.encoding == "jpeg" and m.width > 0 and m.height > 0 for m in msgs)
