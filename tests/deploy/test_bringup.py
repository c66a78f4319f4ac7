"""First bring-up: ``riskfield up --profile robot --dry-run`` starts the robot computer's four nodes
(camera, LIMO bridge, joystick gateway, safety filter) against the real serial protocol on a pty
(the chassis emulator) and a camera source, and the chassis never sees a motion frame."""

from __future__ import annotations

import signal
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

from riskfield.edge.limo import protocol as p
from riskfield.edge.limo.emulator import ChassisEmulator
from riskfield.protocol import Image, Keys, VelocityCommand
from riskfield.testing import Collector, StatusWatch, client_session, free_port, put, wait_alive, wait_until

pytestmark = pytest.mark.slow  # five processes, the filter's kernels among them


def test_robot_profile_dry_run_starts_the_four_nodes_and_keeps_the_wheels_still(tmp_path: Path) -> None:
    pytest.importorskip("av", reason="the camera extra (PyAV) is part of the robot site")
    from PIL import Image as PILImage

    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(3)
    for i in range(3):
        PILImage.fromarray(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)).save(frames / f"{i:03d}.jpg")
    robot = f"t_bringup_{uuid.uuid4().hex[:6]}"
    keys = Keys(robot)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with ChassisEmulator(link=str(tmp_path / "limo")) as emu:
        config = tmp_path / "robot.yaml"
        config.write_text(f"status_period_s: 0.1\nlimo:\n  port: {emu.port}\n  reconnect_s: 0.1\n"
                          f"camera:\n  source: {frames}\n  rate_hz: 5\n  loop: true\n  wait_subscriber: false\n")
        proc = subprocess.Popen([sys.executable, "-m", "riskfield", "up", "--profile", "robot", "--dry-run",
                                 "--listen", endpoint, "--robot", robot, "--config", str(config), "--no-restart"],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            with client_session(endpoint, timeout_s=60) as s:
                images = Collector(s, keys.camera_image, Image)
                status = StatusWatch(s, keys.status("limo"))
                for name in ("camera", "limo", "joystick", "safety-filter"):
                    assert wait_alive(s, keys.alive(name), 90.0), name
                assert wait_until(lambda: emu.model.control_mode == 1, 10.0)  # the real enable went out
                assert images.wait(1, 20.0)

                def ask() -> bool:
                    put(s, keys.cmd_safe, VelocityCommand(linear=(0.4, 0.0, 0.0), angular=(0.0, 0.0, 0.2),
                                                          source="test"))
                    st = status.latest
                    return st is not None and st.extra.get("withheld_commands", 0) >= 3

                assert wait_until(ask, 20.0, period_s=0.05)
                assert status.latest is not None and status.latest.extra["dry_run"] == 1.0
                motions = [m for _, m in emu.frames(p.MotionCommand)]
                assert motions and all(m.is_stop for m in motions)
                assert emu.model.v == 0.0 and emu.model.x == 0.0
                images.close()
                status.close()
            proc.send_signal(signal.SIGINT)
            out, _ = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    assert proc.returncode == 0, out
    assert "dry run: withheld cmd/safe" in out
