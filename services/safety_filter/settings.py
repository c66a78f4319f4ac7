"""Settings of the ``safety-filter`` node: the core's ``FilterConfig`` plus timeouts, the risk
file (``risk_file``) and input limits. Set them in the config file's ``safety-filter`` section,
as ``RISKFIELD_<FIELD>`` variables or with ``--set field=value``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

from ..runtime.arbiter import MAX_PRIORITY, CommandMux, MuxInput
from ..runtime.continuity import StateGateSettings
from ..runtime.risk_file import RiskStateSettings
from ..runtime.settings import NodeSettings, read_config_file
from .config import FilterConfig
from .scale_guard import ScaleGuardConfig

#: Named filter configurations shipped with the package (``presets/<name>.yaml``, a config file's
#: ``safety-filter`` section): ``paper`` is the paper's teleoperation filter.
PRESETS = Path(__file__).parent / "presets"

Seconds = Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)]
Priority = Annotated[int, Field(ge=0, le=MAX_PRIORITY)]
Timeout = Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)]


class RefSource(BaseModel):
    """One ``cmd/ref`` source of the arbitration (``runtime.arbiter``, twist_mux's rules)."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    priority: Priority
    """Higher wins while live; sources below a lock's priority are held while it is on."""
    timeout_s: Timeout = 0.5
    """The source stops counting as live this long after its last claiming command; 0: never."""


def _default_sources() -> dict[str, RefSource]:
    # twist_mux's example configuration (config/twist_mux_topics.yaml): joystick 100, keyboard 90,
    # navigation 10, each with a 0.5 s timeout. Declared order breaks ties.
    return {name: RefSource(priority=p) for name, p in (("joystick", 100), ("ros2/teleop", 100), ("keyboard", 90),
                                                        ("navigator", 10), ("ros2/nav", 10))}


class FilterSettings(NodeSettings, FilterConfig, StateGateSettings, RiskStateSettings):
    SERVICE: ClassVar[str] = "safety-filter"
    REMOVED: ClassVar[dict[str, str]] = {
        "object_match_m": "removed: a moving object is no longer matched to the field's distance; each one on a "
                          "collision course is its own row (collision_horizon_s, object_speed_sigma, "
                          "max_object_rows)",
        "backend": "removed: the filter's step is compiled (numba, in riskfield[robot]); its numpy rendering is a "
                   "test oracle",
        "solver": "removed: the compiled step solves its QP exactly with the dual active-set method; OSQP is its "
                  "test oracle",
    }

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

    ref_sources: dict[str, RefSource] = Field(default_factory=_default_sources, description=(
        "cmd/ref sources by VelocityCommand.source, each {priority, timeout_s}: a command is taken only from "
        "the highest-priority live source (the first listed among equals), as twist_mux does; the joystick "
        "outranks the navigator by default"))
    ref_plain_key: bool = Field(default=True, description=(
        "take references and locks on the plain cmd/ref and cmd/lock keys, trusting the source a message "
        "declares; false: only on cmd/ref/<source> and cmd/lock/<source>, the keys a secure site's routers "
        "let only that source's identity put (protocol.keys.REF_SOURCES)"))
    ref_default_priority: Priority | None = 0
    """Priority of a cmd/ref source not in ref_sources; null: its commands are refused (ref_unknown_source)."""
    ref_default_timeout_s: Timeout = 0.5
    """Timeout of a cmd/ref source not in ref_sources."""
    lock_priority: Priority = MAX_PRIORITY
    """A lock on cmd/lock holds every source of lower priority, and the filter brakes (fallback locked)."""
    lock_timeout_s: Timeout = 0.0
    """0: a lock holds until its source releases it; > 0: a lock source must repeat itself this often,
    and once it has been silent longer its lock is on (a dead lock publisher locks, as in twist_mux)."""

    scale_k_sigma: Annotated[float, Field(ge=0, le=10, allow_inf_nan=False)] = 2.0
    """With perception's alignment (perception/alignment): the field is read as d − k·(σ·d + residual), k this."""
    scale_speed_cap: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.2
    """Speed cap (m/s) while the alignment has not converged or stopped coming."""
    scale_max_range: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 4.0
    """Distances beyond this (m) shrink as much as at it (σ·d is capped here)."""
    alignment_timeout_s: Seconds = 1.0
    """An alignment older than this counts as not converged (the speed cap applies)."""

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

    def command_mux(self) -> CommandMux:
        """The cmd/ref arbitration these settings describe."""
        default = None if self.ref_default_priority is None else (self.ref_default_priority, self.ref_default_timeout_s)
        return CommandMux([MuxInput(n, r.priority, r.timeout_s) for n, r in self.ref_sources.items()],
                          default_input=default, default_lock=(self.lock_priority, self.lock_timeout_s))

    def scale_guard(self) -> ScaleGuardConfig:
        return ScaleGuardConfig(self.scale_k_sigma, self.scale_speed_cap, self.scale_max_range,
                                self.alignment_timeout_s)

    def filter_config(self) -> FilterConfig:
        return FilterConfig.model_validate({k: getattr(self, k) for k in FilterConfig.model_fields})
