"""The joystick's dead-man is never disabled by a blank: ``deadman=""`` is a configuration error
naming the key; driving without one takes the explicit value ``none``."""

from __future__ import annotations

import subprocess
import sys

import pytest
from pydantic import ValidationError

from riskfield.edge.joystick.mapping import CODES
from riskfield.edge.joystick.node import NO_DEADMAN, JoystickSettings


@pytest.mark.parametrize("blank", ["", "   "])
def test_a_blank_deadman_is_a_configuration_error_naming_the_key(blank: str) -> None:
    with pytest.raises(ValidationError, match="deadman is empty") as err:
        JoystickSettings(deadman=blank)
    assert err.value.errors()[0]["loc"] == ("deadman",)


def test_no_deadman_is_an_explicit_value_and_a_typo_is_an_error() -> None:
    assert JoystickSettings().mapping().deadman == CODES["BTN_TRIGGER"]
    assert JoystickSettings(deadman="BTN_THUMB").mapping().deadman == CODES["BTN_THUMB"]
    assert JoystickSettings(deadman="None").mapping().deadman is None
    assert NO_DEADMAN == "none"
    with pytest.raises(ValidationError, match="unknown input code 'BTN_TRIGGR'"):
        JoystickSettings(deadman="BTN_TRIGGR")


def test_riskfield_run_refuses_a_blank_deadman_in_one_message() -> None:
    # Refused while the settings are built, before any connection: the endpoint is never dialled.
    r = subprocess.run([sys.executable, "-m", "riskfield", "run", "joystick", "--set", "deadman=",
                        "-e", "tcp/127.0.0.1:9"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    assert "deadman" in r.stderr and "Traceback" not in r.stderr
