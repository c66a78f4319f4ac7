"""Node configuration: defaults < config file (YAML or TOML) < environment < CLI flags.

The file holds keys shared by every node at the top level and one section per service
(named like the service, ``safety-filter`` or ``safety_filter``)::

    robot: limo1
    connect: [tcp/192.168.1.10:7447]
    safety-filter:
      rate_hz: 50

Environment variables are ``RISKFIELD_<FIELD>`` (``RISKFIELD_CONNECT`` takes a
comma-separated list); nested fields use ``__``. CLI flags are passed as init keywords.

Settings are strict (``extra="forbid"``): a key nobody knows is an ``UnknownSetting`` error
that names the key and the nearest valid one. One file and one environment are shared by
every service of a stack (``riskfield up``, compose env files), so what belongs to someone
else is not an error:

- the service's own section and ``--set`` / init keywords: every key must be a setting of
  this service;
- top-level file keys: a setting of this service is applied, a setting of another known
  service or a service's section is skipped, anything else is an error;
- ``RISKFIELD_*`` variables: likewise, plus ``NOT_SETTINGS`` (the deployment's compose
  variables); variables without the prefix are not ours and ignored.

Which other services exist, and what they accept, is not this module's knowledge: the layer that
starts nodes (the CLI) installs it with ``know_other_services``, as a function called only when a
key is not this node's own (so a node normally imports no other service). Without it, every key
must be this node's own.
"""

from __future__ import annotations

import difflib
import logging
import os
import tomllib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import yaml
from pydantic import AliasChoices, BaseModel, Field, field_validator
from pydantic.fields import FieldInfo
from pydantic_settings import (
    BaseSettings,
    InitSettingsSource,
    NoDecode,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
ENV_PREFIX = "RISKFIELD_"

#: ``RISKFIELD_*`` variables that are no service's settings: the variables docker compose
#: interpolates in ``docker-compose.yml`` and ``deploy/*.yml`` (image, tag, router address and
#: published ports, the robot site's network, secrets, checkpoints), which the docs tell users to
#: export in the shell that every node of the stack also inherits. The bridges' hardware endpoints
#: (``RISKFIELD_LIMO_PORT``, ...) are their settings' aliases, known like any other service's.
NOT_SETTINGS: frozenset[str] = frozenset({
    "SERVER", "TAG", "IMAGE_PREFIX", "SECRETS", "CHECKPOINTS_VOLUME", "CHECKPOINTS_DIR",
    "ROUTER_PORT", "ROBOT_ROUTER_PORT", "ROUTER_REST_PORT", "SERVER_NETWORK", "ROUTER_ADDRESS",
    "ROBOT_ROUTER_ADDRESS", "MAVLINK_ADDRESS", "CAMERA_DEVICE", "CAMERA_CALIBRATION_DIR",
})


#: Settings that were renamed: the old name's error points at the new one.
RENAMED: dict[str, str] = {"risk_config": "risk_file", "risk_config_file": "risk_file",
                           "max_queue": "max_queue_mb"}


class UnknownSetting(ValueError):
    """A key no setting answers to: names the key, where it came from and the nearest valid one."""

    def __init__(self, key: str, service: str, where: str, candidates: Iterable[str], removed: str | None = None):
        self.key, self.service, self.where = key, service, where
        candidates = sorted(set(candidates))
        head, _, leaf = key.rpartition(".")
        renamed = RENAMED.get(leaf.lower().removeprefix(ENV_PREFIX.lower()))
        if renamed is not None:  # old spelling of a setting that exists here, in the same form
            new = f"{head}.{renamed}" if head else (ENV_PREFIX + renamed.upper() if key.isupper() else renamed)
            close = [new] if new in candidates else []
        else:
            close = difflib.get_close_matches(key, candidates, n=1, cutoff=0.6)
        self.suggestion = close[0] if close else None
        hint = f"; did you mean {self.suggestion!r}?" if self.suggestion else ""
        origin = f" ({where})" if where else ""
        if removed is not None:  # a core parameter that is not a setting: say what to use instead
            self.suggestion = None
            super().__init__(f"{key!r}{origin} is not a setting of {service or 'this node'}: {removed}")
            return
        super().__init__(f"unknown setting {key!r}{origin} for {service or 'this node'}{hint}")


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


# -- which keys exist -------------------------------------------------------------------------

def _model_of(field: FieldInfo) -> type[BaseModel] | None:
    ann = field.annotation
    return ann if isinstance(ann, type) and issubclass(ann, BaseModel) else None


def _aliases(name: str, field: FieldInfo) -> list[str]:
    alias = field.validation_alias
    if isinstance(alias, str):
        return [alias]
    if isinstance(alias, AliasChoices):
        return [a for a in alias.choices if isinstance(a, str)]
    return []


def removed_settings(model: type[BaseModel]) -> Mapping[str, str]:
    """Settings a node no longer has (``NodeSettings.REMOVED``) → what replaced them."""
    return getattr(model, "REMOVED", {})


def setting_names(model: type[BaseModel]) -> dict[str, FieldInfo]:
    """Every key a model accepts (field names and string aliases) → its field."""
    out: dict[str, FieldInfo] = {}
    for name, field in model.model_fields.items():
        out[name] = field
        for a in _aliases(name, field):
            out[a] = field
    return out


def _env_vars(name: str, field: FieldInfo) -> list[str]:
    """The variables (upper case) that set one field: its aliases if it has any (a hardware
    endpoint such as ``RISKFIELD_LIMO_PORT``), else ``RISKFIELD_<NAME>``."""
    aliases = _aliases(name, field)
    return [a.upper() for a in aliases] if aliases else [ENV_PREFIX + name.upper()]


def env_names(model: type[BaseModel]) -> dict[str, FieldInfo]:
    """``RISKFIELD_*`` variable (upper case, before any ``__``) → the field it sets."""
    return {var: field for name, field in model.model_fields.items() for var in _env_vars(name, field)}


def check_keys(model: type[BaseModel], data: Mapping[str, Any], service: str, where: str, path: str = "") -> None:
    """Raise ``UnknownSetting`` for the first key of ``data`` (recursing into nested models)
    that ``model`` has no field for."""
    names = setting_names(model)
    for key, value in data.items():
        field = names.get(key)
        if field is None:
            raise UnknownSetting(path + key, service, where, [path + n for n in names],
                                 removed_settings(model).get(key))
        sub = _model_of(field)
        if sub is not None and isinstance(value, Mapping):
            check_keys(sub, value, service, where, f"{path}{key}.")


@dataclass(frozen=True)
class KnownSettings:
    """What the other services of a stack accept: their config-file sections, setting keys and
    ``RISKFIELD_*`` variables, and the services that could not load here (extras not installed)."""

    sections: frozenset[str] = frozenset()
    keys: frozenset[str] = frozenset()
    env: frozenset[str] = frozenset()
    missing: tuple[str, ...] = ()

    @classmethod
    def of(cls, services: Mapping[str, type[BaseModel] | None]) -> KnownSettings:
        """From each service's name and settings class (None: it does not load here)."""
        sections, keys, env = set(), set(), set()
        for name, settings in services.items():
            sections.update({name, name.replace("-", "_")})
            if settings is not None:
                keys.update(setting_names(settings))
                env.update(env_names(settings))
        missing = tuple(name for name, settings in services.items() if settings is None)
        return cls(frozenset(sections), frozenset(keys), frozenset(env), missing)


_other_services: Callable[[], KnownSettings] | None = None


def know_other_services(provider: Callable[[], KnownSettings] | None) -> None:
    """Install what the other services accept, for the keys a shared file or environment holds
    for them (the CLI does, before it builds a node's settings). ``provider`` is called at most
    once, when a key is first found not to be the node's own; None: nothing is known elsewhere."""
    global _other_services
    _other_services = provider
    _known.cache_clear()


@lru_cache(maxsize=1)
def _known() -> KnownSettings:
    return KnownSettings() if _other_services is None else _other_services()


def _unknown(error: UnknownSetting) -> None:
    """Raise ``error``, unless a service that does not load here might own the key: then the
    node must still start (a robot image lacks the server's extras), so only warn."""
    missing = _known().missing
    if not missing:
        raise error
    logging.getLogger("riskfield.settings").warning(
        "%s (ignored: it may belong to %s, not installed here)", error, ", ".join(missing))


def check_environment(model: type[NodeSettings], environ: Mapping[str, str] | None = None) -> None:
    """Refuse ``RISKFIELD_*`` variables that set nothing anywhere (see the module doc)."""
    environ = os.environ if environ is None else environ
    own = env_names(model)
    service = model.SERVICE
    for var in environ:
        upper = var.upper()
        if not upper.startswith(ENV_PREFIX):
            continue  # not ours
        head, _, rest = upper.partition("__")
        field = own.get(head)
        if field is not None:
            sub = _model_of(field)
            if rest and sub is not None:  # RISKFIELD_NAV__K_RHO: one level of nesting is checked
                key = rest.split("__")[0].lower()
                if key not in setting_names(sub):
                    raise UnknownSetting(upper, service, "environment variable",
                                         [f"{head}__{n.upper()}" for n in sub.model_fields])
            continue
        if head[len(ENV_PREFIX):] in NOT_SETTINGS or head in _known().env:
            continue
        removed = removed_settings(model).get(head[len(ENV_PREFIX):].lower())
        if removed is not None:
            raise UnknownSetting(upper, service, "environment variable", own, removed)
        _unknown(UnknownSetting(upper, service, "environment variable", [*own, *_known().env]))


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
        cls: Any = self.settings_cls
        fields = setting_names(cls)
        service: str = getattr(cls, "SERVICE", "")
        own_sections = {service, service.replace("-", "_")} - {""}
        out: dict[str, Any] = {}
        for key, value in data.items():
            if key in fields:
                out[key] = value
                continue
            if key in own_sections:
                continue
            known = _known()
            if key in known.sections or key in known.keys:
                continue  # another service's section or setting: theirs to check
            _unknown(UnknownSetting(key, service, f"top level of {path}", [*fields, *known.sections],
                                    removed_settings(cls).get(key)))
        for name in own_sections:
            section = data.get(name)
            if section is None:
                continue
            if not isinstance(section, dict):
                raise ValueError(f"config file {path}: section {name!r} must be a mapping")
            check_keys(cls, section, service, f"section {name!r} of {path}")
            out.update(section)
        if out:  # top-level keys were checked by name; their nested keys are checked here
            check_keys(cls, out, service, str(path))
        return out


class _CheckedInit(PydanticBaseSettingsSource):
    """The init keywords (CLI flags, ``--set``), checked key by key before pydantic sees them,
    so a typo is named with its nearest valid key rather than as a bare "extra input"."""

    def __init__(self, settings_cls: type[BaseSettings], init: InitSettingsSource):
        super().__init__(settings_cls)
        self._init = init

    def get_field_value(self, field: FieldInfo, field_name: str) -> tuple[Any, str, bool]:  # pragma: no cover
        return None, field_name, False

    def __call__(self) -> dict[str, Any]:
        cls: Any = self.settings_cls
        check_keys(cls, self._init.init_kwargs, getattr(cls, "SERVICE", ""), "")
        check_environment(cls)
        return self._init()


def _split(value: Any) -> Any:
    if isinstance(value, str):
        return [v.strip() for v in value.split(",") if v.strip()]
    return value


class NodeSettings(BaseSettings):
    """What every node needs: Zenoh connection, identity, logging and status period."""

    # A setting's description is the docstring under it (or Field(description=...)): the help
    # (`riskfield run SERVICE --help`) prints it, and a test fails on a setting without one.
    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, env_nested_delimiter="__", extra="forbid",
                                      use_attribute_docstrings=True)
    SERVICE: ClassVar[str] = ""
    #: Settings the node no longer has → what replaced them: setting one is an error that says it.
    REMOVED: ClassVar[dict[str, str]] = {}
    mode: Literal["peer", "client", "router"] = "client"
    """Zenoh session mode: a client dials a router, a peer also talks to peers directly, a router routes."""
    connect: Annotated[list[str], NoDecode] = Field(default_factory=lambda: [DEFAULT_ENDPOINT])
    """Zenoh endpoints to dial, e.g. tcp/192.168.1.10:7447 (RISKFIELD_CONNECT: comma-separated)."""
    listen: Annotated[list[str], NoDecode] = Field(default_factory=list)
    """Zenoh endpoints to listen on (comma-separated in RISKFIELD_LISTEN); none for a client."""
    robot: str = "limo1"
    """Robot id: the second part of every key, {prefix}/{robot}/..."""
    prefix: str = "rf"
    """First part of every key, {prefix}/{robot}/..."""
    config: Path | None = None
    """YAML or TOML file: keys shared by every node at the top level, one section per service."""
    multicast_scouting: bool = False
    """Discover routers and peers by UDP multicast, in addition to the connect endpoints."""
    # Optional security (see deploy/zenoh): TLS (mutual when a client cert is given) and user/password.
    tls_root_ca: Path | None = None
    """CA certificate (PEM) that the router's TLS certificate must chain to."""
    tls_cert: Path | None = None
    """This node's TLS certificate (PEM), presented with tls_key on tls/ endpoints."""
    tls_key: Path | None = None
    """Private key (PEM) of tls_cert."""
    tls_mtls: bool = False
    """Mutual TLS: the router must also check this node's certificate (needs tls_cert and tls_key)."""
    user: str | None = None
    """Zenoh user/password authentication: the user name (with password or password_file)."""
    password: str | None = None
    """Password of user; password_file keeps it out of the environment."""
    password_file: Path | None = Field(default=None, description="file holding the password (Docker/systemd secrets)")
    zenoh_config: Path | None = Field(default=None, description="a full zenoh JSON5 config used as the base")
    insecure: bool = False
    """Listen beyond loopback without TLS and users anyway: anyone who reaches the port may put any key,
    cmd/safe included. Without it such a node refuses to start; with it, it warns at start."""
    published_on: str | None = None
    """In a container: the host address its listen port is published on (compose `ports:`). The
    listeners then count as reachable from that address only (docker-compose.yml sets it; never on a host)."""
    connect_timeout_s: float = Field(default=30.0, gt=0)
    """How long a node retries opening its session while no router answers, then exits with code 3."""
    log_level: str = "INFO"
    """Python logging level: DEBUG, INFO, WARNING or ERROR."""
    status_period_s: float = Field(default=1.0, gt=0)
    """Period of the node's status message (counters, rates) on {prefix}/{robot}/status/{service}."""
    heap_trim_s: float = Field(default=1.0, ge=0, description=(
        "period of returning freed heap to the OS (glibc malloc_trim; 0 = never): keeps a long-running "
        "node's RSS its live memory (runtime/memory.py)"))

    @field_validator("connect", "listen", mode="before")
    @classmethod
    def _comma_list(cls, v: Any) -> Any:
        return _split(v)

    def zenoh_extra(self) -> dict[str, object]:
        """Zenoh config paths this service sets beyond its endpoints and security, after the base file."""
        return {}

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
        return _CheckedInit(settings_cls, init_settings), env_settings, _FileSource(settings_cls, init_settings)


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
