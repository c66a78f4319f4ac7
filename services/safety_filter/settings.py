"""Settings of the ``safety-filter`` node: the core's ``FilterConfig`` plus timeouts, the risk
file (``risk_file``) and input limits. Set them in the config file's ``safety-filter`` section,
as ``RISKFIELD_<FIELD>`` variables or with ``--set field=value``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, ClassVar

from pydantic import Field, model_validator

from ..runtime.continuity import StateGateSettings
from ..runtime.settings import NodeSettings, read_config_file
from .config import REFERENCE_IMPLEMENTATIONS, FilterConfig

#: Named filter configurations shipped with the package (``presets/<name>.yaml``, a config file's
#: ``safety-filter`` section): ``paper`` is the paper's teleoperation filter.
PRESETS = Path(__file__).parent / "presets"

Seconds = Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)]


class FilterSettings(NodeSettings, FilterConfig, StateGateSettings):
    SERVICE: ClassVar[str] = "safety-filter"
    REFERENCE_ONLY: ClassVar[dict[str, str]] = REFERENCE_IMPLEMENTATIONS

    map_timeout_s: Seconds = 0.3
    """A map whose content is older than this (plus clock_tolerance_s) makes the filter brake (stale_map)."""
    state_timeout_s: Seconds = 0.3
    """No state newer than this: the filter brakes (stale_state)."""
    ref_timeout_s: Seconds = 0.2
    """No reference command newer than this: the filter brakes (stale_ref)."""
    clock_tolerance_s: Annotated[float, Field(ge=0, le=60, allow_inf_nan=False, description=(
        "how far the clock that stamped the map may be from this one: the map's content age "
        "(now - header stamp) may reach map_timeout_s + clock_tolerance_s"))] = 0.1
    # 0.1 s: one host has no offset and chrony on a LAN a few ms, while the sum with map_timeout_s
    # (0.4 s) bounds how long the robot drives on after perception dies, the last map's
    # perception latency included (tests/deploy/test_soak.py: a brake within 0.5 s of the kill).
    risk_file: Path | None = Field(default=None, description="YAML/TOML/JSON RiskConfig, watched for changes")
    risk_poll_s: Seconds = 1.0
    """How often risk_file is checked for changes."""
    max_map_bytes: Annotated[int, Field(gt=0)] = 64 * 1024 * 1024
    """Largest ESDF array accepted (bytes); a larger map is refused and counted."""
    step_on_map: bool = Field(default=True, description=(
        "step (and publish cmd/safe) as soon as a map is taken, not only on a reference or a tick; "
        "false: the previous scheduling, kept for `riskfield bench latency --previous`"))

    preset: str | None = Field(default=None, description=(
        "a named filter configuration shipped with riskfield (safety_filter/presets/<name>.yaml, e.g. "
        "paper): its values replace the defaults; the config file, environment and --set still override it"))

    @model_validator(mode="before")
    @classmethod
    def _preset_under_the_rest(cls, data: Any) -> Any:
        # The preset is read like a config file (runtime.settings.read_config_file) and slots in
        # just above the defaults: whatever the sources set explicitly wins.
        if not isinstance(data, dict) or not data.get("preset"):
            return data
        path = PRESETS / f"{data['preset']}.yaml"
        if not path.is_file():
            known = sorted(p.stem for p in PRESETS.glob("*.yaml"))
            raise ValueError(f"preset {data['preset']!r} is not one of {known}")
        return {**read_config_file(path)[cls.SERVICE], **data}

    def filter_config(self) -> FilterConfig:
        return FilterConfig.model_validate({k: getattr(self, k) for k in FilterConfig.model_fields})
