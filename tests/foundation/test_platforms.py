"""One home for the LIMO's figures (``protocol/platforms.py``): the bridge, its emulator and the
simulator read them there instead of keeping copies that drift apart."""

from __future__ import annotations

import pytest

from riskfield.protocol.platforms import LIMO, PlanarPlatform


def test_the_bridge_emulator_and_simulator_read_the_one_limo() -> None:
    from riskfield.edge.limo.bridge import BridgeConfig
    from riskfield.edge.limo.emulator import ChassisModel
    from riskfield.edge.limo.kinematics import LimoLimits
    from riskfield.edge.limo.node import LimoSettings
    from riskfield.services.simulator import robots

    limits = LimoLimits()
    for name in ("max_linear", "max_lateral", "max_angular", "max_wheel_speed", "max_steering", "wheelbase", "track"):
        assert getattr(limits, name) == getattr(LIMO, name), name
    assert BridgeConfig().limits.max_angular == LIMO.max_angular
    assert LimoSettings.model_fields["max_angular"].default == LIMO.max_angular  # composed, not repeated
    emu = ChassisModel()
    assert (emu.wheelbase, emu.track) == (LIMO.wheelbase, LIMO.track)
    sim = robots.LIMO
    assert (sim.v_max, sim.w_max, sim.a_max, sim.alpha_max) == (LIMO.max_linear, LIMO.max_angular, LIMO.max_accel,
                                                                 LIMO.max_yaw_accel)
    assert (robots.LIMO_WHEELBASE, robots.LIMO_MAX_STEER, robots.LIMO_MECANUM.vy_max) == (
        LIMO.wheelbase, LIMO.max_steering, LIMO.max_lateral)


def test_a_platform_is_strict_and_frozen() -> None:
    with pytest.raises(ValueError, match="max_linear"):
        PlanarPlatform(**{**LIMO.model_dump(), "max_linear": 0.0})
    with pytest.raises(ValueError, match="max_linaer"):
        PlanarPlatform(**LIMO.model_dump(), max_linaer=1.0)
    with pytest.raises(ValueError):
        LIMO.max_linear = 3.0  # type: ignore[misc]
