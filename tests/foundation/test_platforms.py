"""One description per robot (``protocol/platforms.py``): the bridges, the emulator, the simulator's
plants, the filter's body and bounds and the navigator read it there instead of keeping copies that
drift apart; a new robot is one description."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import pytest

from riskfield.protocol import platforms
from riskfield.protocol.platforms import LIMO, MULTICOPTER, POINT_MASS, PlanarPlatform, SpatialPlatform

REPO = Path(__file__).resolve().parents[2]
#: The packages that ship (setup.py maps these folders onto ``riskfield``); tests and examples do not.
SHIPPED = ("protocol", "services", "edge", "riskfield")


def shipped_trees() -> list[tuple[Path, ast.Module]]:
    return [(f, ast.parse(f.read_text(), str(f))) for d in SHIPPED for f in sorted((REPO / d).rglob("*.py"))]


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
    ackermann = robots.make_robot("ackermann")
    assert (ackermann.wheelbase, ackermann.max_steer, robots.LIMO_MECANUM.vy_max) == (  # type: ignore[attr-defined]
        LIMO.wheelbase, LIMO.max_central_steering, LIMO.max_lateral)


def test_a_platform_is_strict_and_frozen() -> None:
    with pytest.raises(ValueError, match="max_linear"):
        PlanarPlatform(**{**LIMO.model_dump(), "max_linear": 0.0})
    with pytest.raises(ValueError, match="max_linaer"):
        PlanarPlatform(**LIMO.model_dump(), max_linaer=1.0)
    with pytest.raises(ValueError):
        LIMO.max_linear = 3.0  # type: ignore[misc]


def test_each_model_and_plant_class_name_is_defined_once_in_shipped_code() -> None:
    """The filter's barrier models and the simulator's plants are different things: no class name
    (``DoubleIntegrator`` above all) is defined twice."""
    where: dict[str, list[str]] = {}
    for f, tree in shipped_trees():
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                where.setdefault(node.name, []).append(str(f.relative_to(REPO)))
    assert where["DoubleIntegrator"] == ["services/safety_filter/barriers.py"]
    assert where["SingleIntegrator"] == ["services/safety_filter/barriers.py"]
    for name in ("Unicycle", "Ackermann", "Mecanum"):
        assert name not in where, (name, where.get(name))
    for name in ("DifferentialPlant", "AckermannPlant", "MecanumPlant", "VelocityPointPlant", "PointMassPlant"):
        assert where[name] == ["services/simulator/robots.py"], name


def test_the_limo_figures_are_written_once_in_shipped_code() -> None:
    """Its body, track, inner steering limit (pylimo's 0.48869 too) and what follows from them
    (half the body, the central steering limit) appear as numbers only in its description."""
    figures = {LIMO.length, LIMO.track, LIMO.max_steering, 0.48869, LIMO.length / 2,
               round(LIMO.max_central_steering, 3), round(LIMO.max_central_steering, 4)}
    found = [(str(f.relative_to(REPO)), n.lineno, n.value) for f, tree in shipped_trees() for n in ast.walk(tree)
             if isinstance(n, ast.Constant) and type(n.value) is float and n.value in figures]
    assert {f for f, _, _ in found} == {"protocol/platforms.py"}, found
    assert len(found) == 3  # length, track, max_steering, in the one PlanarPlatform(...) call


def test_the_simulators_ackermann_steers_to_the_central_limit_the_bridge_uses() -> None:
    """The 0.488 rad limit is the inner wheel's; the bicycle model's is the central angle there."""
    from riskfield.edge.limo.kinematics import LimoLimits
    from riskfield.services.simulator.robots import make_robot

    sim = make_robot("ackermann")
    bridge = LimoLimits()
    assert sim.max_steer == pytest.approx(bridge.max_central_steering)  # type: ignore[attr-defined]
    assert sim.max_steer < LIMO.max_steering - 0.07  # type: ignore[attr-defined]
    assert sim.min_turning_radius == pytest.approx(1.0 / bridge.max_curvature)  # type: ignore[attr-defined]


def test_a_new_robot_is_one_description(monkeypatch: pytest.MonkeyPatch) -> None:
    """A differential-drive robot described once: the simulator's plant, the filter's body and
    bounds, the navigator and the LIMO-protocol bridge's limits all come from it."""
    from riskfield.edge.limo.kinematics import LimoLimits
    from riskfield.services.navigator.config import NavigatorConfig
    from riskfield.services.safety_filter.config import FilterConfig, platform_bounds, platform_footprint
    from riskfield.services.simulator.robots import DifferentialPlant, make_robot, resolve_robot_type

    scout = PlanarPlatform(name="scout", kinematics=("differential",), length=0.6, width=0.5, wheelbase=0.45,
                           track=0.4, max_linear=0.7, max_lateral=0.1, max_angular=1.2, max_wheel_speed=0.9,
                           max_steering=0.3, max_accel=0.8, max_yaw_accel=2.0)
    monkeypatch.setitem(platforms.PLATFORMS, "scout", scout)
    plant = make_robot("scout", (1.0, 2.0, 0.0))
    assert isinstance(plant, DifferentialPlant)
    assert (plant.limits.v_max, plant.limits.w_max, plant.limits.a_max, plant.limits.vy_max) == (0.7, 1.2, 0.8, 0.0)
    with pytest.raises(ValueError, match="scout drives differential, not ackermann"):
        resolve_robot_type("scout:ackermann")
    cfg = FilterConfig(footprint=platform_footprint(scout), **platform_bounds(scout))
    assert (cfg.v_max, cfg.w_max, cfg.a_max) == (0.7, 1.2, 0.8)
    assert (cfg.body().length, cfg.body().width) == (0.6, 0.5)
    nav = NavigatorConfig(platform="scout", v_max=2.0, w_max=2.0).unicycle()
    assert (nav.v_max, nav.w_max) == (0.7, 1.2)
    with pytest.raises(ValueError, match="not a point robot"):
        NavigatorConfig(platform="scout", model="double_integrator")
    limits = LimoLimits.of(scout)
    assert (limits.max_linear, limits.track, limits.wheelbase) == (0.7, 0.4, 0.45)


def test_every_robot_type_is_a_platform_and_a_kinematics() -> None:
    from riskfield.edge.mavlink.convert import VelocityLimits
    from riskfield.services.simulator import robots

    assert set(robots.KINEMATICS) == {"differential", "ackermann", "mecanum", "single_integrator",
                                      "double_integrator"}
    for name, p in platforms.PLATFORMS.items():
        for kin in p.kinematics:
            plant = robots.make_robot(f"{name}:{kin}")
            assert isinstance(plant, robots.KINEMATICS[kin])
    for kind in robots.ROBOT_TYPES:  # the names scenarios have always used still work
        robots.make_robot(kind)
    with pytest.raises(ValueError, match="use one of limo, ackermann"):
        robots.make_robot("tank")
    pm = robots.make_robot("double_integrator")
    assert (pm.v_max, pm.w_max, pm.a_max) == (POINT_MASS.max_speed, POINT_MASS.max_yaw_rate, 3.0)  # type: ignore
    assert (pm.v_max, pm.a_max) == (2.0, 3.0)  # type: ignore[attr-defined]  # the benchmark's, unchanged
    v = VelocityLimits()
    assert (v.max_horizontal, v.max_vertical, v.max_yaw_rate) == (MULTICOPTER.max_speed, MULTICOPTER.max_vertical,
                                                                  MULTICOPTER.max_yaw_rate)
    assert isinstance(MULTICOPTER, SpatialPlatform) and math.isclose(LIMO.min_turning_radius, 0.4628, abs_tol=1e-4)
    with pytest.raises(ValueError, match="unknown platform 'tank'"):
        platforms.platform("tank")

