"""Node configuration: defaults < config file (YAML or TOML) < environment < CLI flags.

The file holds keys shared by every node at the top level and one section per service
(named like the service, ``safety-filter`` or ``safety_filter``)::

    robot: limo1
    connect: [tcp/192.168.1.10:7447]
    safety-filter:
      rate_hz: 50

Environment variables are ``RISKFIELD_<FIELD>`` (``RISKFIELD_CONNECT`` takes a
comma-separated list); nested fields use ``__``. CLI flags are passed as init keywords.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import yaml
from pydantic import Field, field_validator
from pydantic.fields import FieldInfo
from pydantic_settings import (
    BaseSettings,
    InitSettingsSource,
    NoDecode,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def read_config_file(path: str | Path) -> dict[str, Any]:
    """Parse a YAML (.yaml/.yml) or TOML (.toml) file into a dict; a clear error otherwise."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"config file {p} does not exist")
    text = p.read_text()
    if p.suffix == ".toml":
        data = tomllib.loads(text)
    elif p.suffix in (".yaml", ".yml", ".json"):
        data = yaml.safe_load(text) or {}
    else:
        raise ValueError(f"config file {p}: use .yaml, .yml or .toml")
    if not isinstance(data, dict):
        raise ValueError(f"config file {p}: the top level must be a mapping")
    return data


class _FileSource(PydanticBaseSettingsSource):
    """Top-level keys plus the service's own section of the config file."""

    def __init__(self, settings_cls: type[BaseSettings], init: InitSettingsSource):
        super().__init__(settings_cls)
        self._init = init

    def get_field_value(self, field: FieldInfo, field_name: str) -> tuple[Any, str, bool]:  # pragma: no cover
        return None, field_name, False

    def __call__(self) -> dict[str, Any]:
        path = self._init.init_kwargs.get("config") or os.environ.get("RISKFIELD_CONFIG")
        if not path:
            return {}
        data = read_config_file(path)
        fields = self.settings_cls.model_fields
        out = {k: v for k, v in data.items() if k in fields}
        service = getattr(self.settings_cls, "SERVICE", "")
        for name in {service, service.replace("-", "_")}:
            section = data.get(name) if name else None
            if isinstance(section, dict):
                out.update(section)
        return out


def _split(value: Any) -> Any:
    if isinstance(value, str):
        return [v.strip() for v in value.split(",") if v.strip()]
    return value


class NodeSettings(BaseSettings):
    """What every node needs: Zenoh connection, identity, logging and status period."""

    model_config = SettingsConfigDict(env_prefix="RISKFIELD_", env_nested_delimiter="__", extra="ignore")
    SERVICE: ClassVar[str] = ""

    mode: Literal["peer", "client", "router"] = "client"
    connect: Annotated[list[str], NoDecode] = Field(default_factory=lambda: [DEFAULT_ENDPOINT])
    listen: Annotated[list[str], NoDecode] = Field(default_factory=list)
    robot: str = "limo1"
    prefix: str = "rf"
    config: Path | None = None
    multicast_scouting: bool = False
    # Optional security (see deploy/zenoh): TLS (mutual when a client cert is given) and user/password.
    tls_root_ca: Path | None = None
    tls_cert: Path | None = None
    tls_key: Path | None = None
    tls_mtls: bool = False
    user: str | None = None
    password: str | None = None
    password_file: Path | None = Field(default=None, description="file holding the password (Docker/systemd secrets)")
    zenoh_config: Path | None = Field(default=None, description="a full zenoh JSON5 config used as the base")
    connect_timeout_s: float = Field(default=30.0, gt=0)
    log_level: str = "INFO"
    status_period_s: float = Field(default=1.0, gt=0)

    @field_validator("connect", "listen", mode="before")
    @classmethod
    def _comma_list(cls, v: Any) -> Any:
        return _split(v)

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        assert isinstance(init_settings, InitSettingsSource)
        return init_settings, env_settings, _FileSource(settings_cls, init_settings)


def parse_overrides(pairs: list[str]) -> dict[str, Any]:
    """``["rate_hz=50", "risk.groups=[...]"]`` → a nested dict; values are YAML scalars/lists."""
    out: dict[str, Any] = {}
    for pair in pairs:
        if "=" not in pair:
            raise ValueError(f"--set {pair!r}: expected key=value")
        key, raw = pair.split("=", 1)
        value = yaml.safe_load(raw) if raw.strip() else ""
        node = out
        *parents, leaf = key.strip().replace("-", "_").split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return out
