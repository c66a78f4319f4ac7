"""Strict settings: a typo in a file, ``--set`` or a ``RISKFIELD_*`` variable is an error that
names the key and the nearest valid one; what belongs to another service is not."""

from __future__ import annotations

import subprocess
import sys

import pytest

from riskfield.services.runtime import UnknownSetting
from riskfield.services.runtime.settings import KnownSettings, check_environment, know_other_services
from riskfield.services.safety_filter.settings import FilterSettings


@pytest.fixture(autouse=True)
def stack():
    """What the CLI tells the runtime before it builds a node's settings: the other services'
    keys (a node started by ``riskfield run`` knows them; the runtime alone knows none)."""
    from riskfield.cli import every_service_settings

    know_other_services(every_service_settings)
    yield
    know_other_services(None)


@pytest.fixture
def env(monkeypatch):
    import os

    for var in list(os.environ):
        if var.upper().startswith("RISKFIELD_"):
            monkeypatch.delenv(var)
    return monkeypatch


def test_set_typo_names_key_and_suggestion(env):
    with pytest.raises(UnknownSetting, match=r"unknown setting 'robot_raduis' for safety-filter; "
                                             r"did you mean 'robot_radius'\?"):
        FilterSettings(robot_raduis=0.5)


def test_nested_typo_names_the_dotted_key(env):
    from riskfield.services.navigator.node import NavigatorSettings

    with pytest.raises(UnknownSetting, match=r"'nav.k_rhoo'.*did you mean 'nav.k_rho'"):
        NavigatorSettings(nav={"k_rhoo": 1.0})


def test_env_typo_names_variable_and_suggestion(env):
    env.setenv("RISKFIELD_ROBOT_RADUIS", "0.5")
    with pytest.raises(UnknownSetting, match=r"'RISKFIELD_ROBOT_RADUIS' \(environment variable\) for "
                                             r"safety-filter; did you mean 'RISKFIELD_ROBOT_RADIUS'\?"):
        FilterSettings()


def test_env_of_other_services_hardware_and_foreign_variables_are_ignored(env):
    env.setenv("PATH_LIKE_THING", "x")
    env.setenv("robot_raduis", "1")  # no prefix: not ours
    env.setenv("RISKFIELD_VOXEL_SIZE", "0.1")  # a mapping setting
    env.setenv("RISKFIELD_LIMO_PORT", "/dev/ttyUSB0")  # hardware endpoint of the LIMO bridge
    env.setenv("RISKFIELD_JOYSTICK_DEVICE", "/dev/input/event3")
    env.setenv("RISKFIELD_MAVLINK_URL", "udpin:127.0.0.1:14550")
    env.setenv("RISKFIELD_SERVER", "tcp/10.0.0.2:7447")  # compose interpolation
    env.setenv("RISKFIELD_ROBOT_RADIUS", "0.3")
    s = FilterSettings()
    assert s.robot_radius == 0.3
    check_environment(FilterSettings, {"HOME": "/root", "PATH": "/usr/bin"})


def test_nested_env_typo(env):
    from riskfield.services.navigator.node import NavigatorSettings

    env.setenv("RISKFIELD_NAV__K_RHO", "0.5")
    assert NavigatorSettings().nav.k_rho == 0.5
    env.setenv("RISKFIELD_NAV__K_RHOO", "0.5")
    with pytest.raises(UnknownSetting, match="did you mean 'RISKFIELD_NAV__K_RHO'"):
        NavigatorSettings()


def test_file_typos_in_own_section_and_top_level(env, tmp_path):
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("robot: r1\nsafety-filter:\n  robot_raduis: 0.5\n")
    with pytest.raises(UnknownSetting, match=r"'robot_raduis' \(section 'safety-filter' of .*cfg.yaml\).*"
                                             r"did you mean 'robot_radius'"):
        FilterSettings(config=cfg)
    cfg.write_text("robt: r1\n")
    with pytest.raises(UnknownSetting, match=r"'robt' \(top level of .*\).*did you mean 'robot'"):
        FilterSettings(config=cfg)


def test_file_sections_and_keys_of_other_services_are_not_errors(env, tmp_path):
    cfg = tmp_path / "cfg.toml"
    cfg.write_text('robot = "r2"\nvoxel_size = 0.1\n[mapping]\nvoxel_sise = 0.1\n[safety_filter]\nrate_hz = 40\n')
    s = FilterSettings(config=cfg)
    assert (s.robot, s.rate_hz) == ("r2", 40.0)


def test_cli_set_typo_exits_2_without_traceback(env):
    r = subprocess.run([sys.executable, "-m", "riskfield", "run", "safety-filter", "--set", "robot_raduis=0.5"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "unknown setting 'robot_raduis' for safety-filter; did you mean 'robot_radius'?" in r.stderr
    assert "Traceback" not in r.stderr


def test_cli_env_typo_exits_2_without_traceback(env):
    import os

    r = subprocess.run([sys.executable, "-m", "riskfield", "run", "relay"], capture_output=True, text=True,
                       timeout=60, env={**os.environ, "RISKFIELD_SCHEMA_NAM": "VelocityCommand/1"})
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "did you mean 'RISKFIELD_SCHEMA_NAME'?" in r.stderr


def test_core_parameters_are_composed_of_per_stage_structs():
    from riskfield.services.mapping.config import (
        DynamicParams,
        EsdfParams,
        FloorParams,
        MapperConfig,
        ObjectParams,
        OccupancyParams,
        TsdfParams,
        VolumeParams,
    )
    from riskfield.services.safety_filter.config import (
        BarrierParams,
        BoundsParams,
        FilterConfig,
        MotionParams,
        QpParams,
    )

    m = MapperConfig.compose(volume=VolumeParams(voxel_size=0.1), tsdf=TsdfParams(truncation=0.3),
                             esdf=EsdfParams(output="3d"))
    assert (m.voxel_size, m.truncation, m.output, m.min_weight) == (0.1, 0.3, "3d", OccupancyParams().min_weight)
    assert m.tsdf == TsdfParams(truncation=0.3) and m.volume.shape == m.shape
    parts = [VolumeParams, TsdfParams, OccupancyParams, EsdfParams, DynamicParams, ObjectParams, FloorParams]
    assert sum(len(p.model_fields) for p in parts) == len(MapperConfig.model_fields)  # no field left out
    f = FilterConfig.compose(barrier=BarrierParams(robot_radius=0.3), bounds=BoundsParams(v_max=0.5))
    assert (f.robot_radius, f.v_max, f.rate_hz) == (0.3, 0.5, QpParams().rate_hz)
    assert f.barrier_params.robot_radius == 0.3 and f.qp_params == QpParams()
    parts = [BarrierParams, BoundsParams, QpParams, MotionParams]
    assert sum(len(p.model_fields) for p in parts) == len(FilterConfig.model_fields)
    with pytest.raises(ValueError, match="robot_raduis"):  # the cores are strict too
        FilterConfig(robot_raduis=0.5)
    with pytest.raises(ValueError, match="min_depth must be below max_depth"):  # a stage's own check still runs
        MapperConfig(min_depth=7.0)


def test_an_unknown_variable_only_warns_when_a_service_cannot_load_here(env, monkeypatch, caplog):
    """A robot image lacks the server's extras: the key might be mapping's, so the filter starts."""
    from riskfield.cli import every_service_settings

    known = every_service_settings()
    know_other_services(lambda: KnownSettings(known.sections, frozenset(), frozenset(), ("mapping",)))
    env.setenv("RISKFIELD_VOXEL_SIZE", "0.1")
    with caplog.at_level("WARNING", "riskfield.settings"):
        FilterSettings()
    assert "RISKFIELD_VOXEL_SIZE" in caplog.text and "mapping, not installed here" in caplog.text


def test_a_service_that_cannot_run_here_still_has_its_settings_checked(env, monkeypatch):
    """The viewer needs rerun only to run: without it, its keys are still known, so a typo in a
    shared file is an error rather than a warning that it might be the viewer's."""
    import importlib.util

    from riskfield.cli import every_service_settings
    from riskfield.services.runtime import ServiceUnavailable, load_service

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "rerun" else find_spec(name, *a))
    with pytest.raises(ServiceUnavailable, match="rerun"):
        load_service("viewer")  # it cannot run here
    known = every_service_settings()
    assert "viewer" not in known.missing and "live" in known.keys
    know_other_services(lambda: known)
    env.setenv("RISKFIELD_VOXEL_SIZ", "0.1")
    with pytest.raises(ValueError, match="RISKFIELD_VOXEL_SIZ"):
        FilterSettings()


def _env_file(path) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            key, _, value = line.partition("=")
            out[key.strip()] = value.strip()
    return out


@pytest.mark.parametrize("overlay", [None, "deploy/compose.secure.yml"])
def test_every_shipped_container_environment_is_accepted_by_its_service(overlay):
    """The env files are shared by several services: each container must start with its own."""
    from pathlib import Path

    import yaml

    from riskfield.services.runtime import load_service

    root = Path(__file__).resolve().parents[2]
    services = yaml.safe_load((root / "docker-compose.yml").read_text())["services"]
    if overlay:  # compose replaces env_file and merges environment; the command comes from the base
        for name, extra in yaml.safe_load((root / overlay).read_text())["services"].items():
            base = services.setdefault(name, {})
            base["environment"] = {**(base.get("environment") or {}), **(extra.get("environment") or {})}
            base["env_file"] = extra.get("env_file", base.get("env_file"))
    checked = 0
    for svc in services.values():
        cmd = svc.get("command") or []
        if len(cmd) < 2 or cmd[0] != "run":
            continue
        files = svc.get("env_file") or []
        environ = {k: v for f in ([files] if isinstance(files, str) else files) if "$" not in f
                   for k, v in _env_file(root / f).items()}
        environ.update({k: str(v) for k, v in (svc.get("environment") or {}).items()})
        check_environment(load_service(cmd[1]).settings, environ)  # raises on a key nobody owns
        checked += 1
    assert checked >= 6


def test_renamed_settings_point_at_the_new_name(env):
    from riskfield.services.mapping.settings import MappingSettings

    with pytest.raises(UnknownSetting, match="'risk_config' for safety-filter; did you mean 'risk_file'"):
        FilterSettings(risk_config="/tmp/risk.yaml")
    with pytest.raises(UnknownSetting, match="'risk_config_file' for mapping; did you mean 'risk_file'"):
        MappingSettings(risk_config_file="/tmp/risk.yaml")
    env.setenv("RISKFIELD_RISK_CONFIG", "/tmp/risk.yaml")
    with pytest.raises(UnknownSetting, match="did you mean 'RISKFIELD_RISK_FILE'"):
        FilterSettings()


def test_without_the_other_services_known_a_key_of_theirs_is_an_error(env, tmp_path):
    """The runtime knows no service: only the layer above (the CLI) makes another service's
    keys acceptable."""
    know_other_services(None)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("voxel_size: 0.1\n")
    with pytest.raises(UnknownSetting, match="'voxel_size'"):
        FilterSettings(config=cfg)
    env.setenv("RISKFIELD_LIMO_PORT", "/dev/ttyUSB0")
    with pytest.raises(UnknownSetting, match="RISKFIELD_LIMO_PORT"):
        FilterSettings()


def test_a_shared_file_is_accepted_by_a_node_started_from_the_cli(env, tmp_path):
    """``riskfield run`` in a fresh process: the CLI installs the other services' keys."""
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("voxel_size: 0.1\n")  # mapping's: skipped, not refused
    r = subprocess.run([sys.executable, "-m", "riskfield", "run", "relay", "--config", str(cfg),
                        "--connect", "tcp/127.0.0.1:9", "--set", "connect_timeout_s=0.1"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 3 and "no Zenoh router" in r.stderr, r.stderr  # past the settings, at the session


def test_a_removed_reference_implementation_fails_naming_what_replaced_it(env, tmp_path):
    """The ESDF's reference options are gone: as a setting (argument, file, variable) and as a core
    parameter, each is refused with the message that names what replaced it."""
    from pydantic import ValidationError

    from riskfield.services.mapping.config import EsdfParams, MapperConfig
    from riskfield.services.mapping.settings import MappingSettings

    with pytest.raises(ValidationError, match=r"'esdf_kernel' is not a parameter: removed: .*compiled passes"):
        MapperConfig(esdf_kernel="numpy")
    with pytest.raises(ValidationError, match=r"'esdf_update' is not a parameter: removed: .*incrementally"):
        EsdfParams(esdf_update="full")
    with pytest.raises(UnknownSetting, match=r"'esdf_kernel' is not a setting of mapping: removed: .*compiled"):
        MappingSettings(esdf_kernel="numpy")
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("mapping:\n  esdf_edt: edt\n")
    with pytest.raises(UnknownSetting, match=r"'esdf_edt' \(section 'mapping' .*\) is not a setting.*removed: .*"
                                             r"distance_transform"):
        MappingSettings(config=cfg)
    env.setenv("RISKFIELD_ESDF_UPDATE", "full")
    with pytest.raises(UnknownSetting, match=r"RISKFIELD_ESDF_UPDATE.*not a setting.*removed: .*esdf_incremental"):
        MappingSettings()
    env.delenv("RISKFIELD_ESDF_UPDATE")
    assert MappingSettings(esdf_incremental="wave").mapper_config().esdf_incremental == "wave"  # a real option stays


def test_the_per_pixel_ray_integration_is_refused_naming_what_replaced_it(env, tmp_path):
    """``integration = "ray"`` (one ray per pixel) is a test oracle now, and ``carve_stride`` strided
    only its carving: as a core parameter and as a setting (argument, file, variable), each is refused
    with the message that names what replaced it; the kept modes stay."""
    from pydantic import ValidationError

    from riskfield.services.mapping.config import MapperConfig, TsdfParams
    from riskfield.services.mapping.settings import MappingSettings

    ray = r"integration 'ray' is removed: frames with intrinsics take 'projective'.*'merged'.*tests/oracles/tsdf.py"
    with pytest.raises(ValidationError, match=ray):
        TsdfParams(integration="ray")
    with pytest.raises(ValidationError, match=ray):
        MapperConfig(integration="ray")
    with pytest.raises(ValidationError, match=ray):
        MappingSettings(integration="ray")
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("mapping:\n  integration: ray\n")
    with pytest.raises(ValidationError, match=ray):
        MappingSettings(config=cfg)
    env.setenv("RISKFIELD_INTEGRATION", "ray")
    with pytest.raises(ValidationError, match=ray):
        MappingSettings()
    env.delenv("RISKFIELD_INTEGRATION")
    with pytest.raises(ValidationError, match=r"'carve_stride' is not a parameter: removed: .*tests/oracles/tsdf.py"):
        TsdfParams(carve_stride=2)
    with pytest.raises(ValidationError, match=r"'carve_stride' is not a parameter: removed"):
        MapperConfig(carve_stride=2)
    with pytest.raises(UnknownSetting, match=r"'carve_stride' is not a setting of mapping: removed: .*merged"):
        MappingSettings(carve_stride=2)
    with pytest.raises(ValidationError, match="literal_error"):
        TsdfParams(integration="per-pixel")  # any other unknown value: pydantic's own error
    for mode in ("projective", "merged"):
        assert MappingSettings(integration=mode).mapper_config().integration == mode


def test_the_filters_removed_settings_fail_naming_what_replaced_them(env, tmp_path):
    """``backend`` and ``solver`` chose the numpy step and OSQP, test oracles now: setting either is an
    error that names the compiled step, from keyword, file and environment alike."""
    from pydantic import ValidationError

    from riskfield.services.safety_filter.config import FilterConfig

    with pytest.raises(ValidationError):
        FilterConfig(backend="numpy")  # type: ignore[call-arg]
    with pytest.raises(UnknownSetting, match=r"'backend' is not a setting of safety-filter: removed: the filter's "
                                             r"step is compiled"):
        FilterSettings(backend="numpy")
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("safety-filter:\n  solver: osqp\n")
    with pytest.raises(UnknownSetting, match=r"'solver' \(section 'safety-filter' .*\) is not a setting.*dual "
                                             r"active-set.*OSQP is its test oracle"):
        FilterSettings(config=cfg)
    env.setenv("RISKFIELD_SOLVER", "osqp")
    with pytest.raises(UnknownSetting, match=r"RISKFIELD_SOLVER.*not a setting.*removed"):
        FilterSettings()
