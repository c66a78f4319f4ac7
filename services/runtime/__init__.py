"""The shared service runtime: settings, Zenoh session, node loop, service registry."""

from .inbox import Inbox
from .logs import RateLimitedLog, setup_logging
from .node import Node
from .service import SERVICES, ServiceSpec, ServiceUnavailable, build_settings, load_service, run_service
from .session import endpoint_config, open_session, zenoh_config
from .settings import DEFAULT_ENDPOINT, NodeSettings, UnknownSetting, parse_overrides, read_config_file

__all__ = [
    "DEFAULT_ENDPOINT", "SERVICES", "Inbox", "Node", "NodeSettings", "RateLimitedLog", "ServiceSpec",
    "ServiceUnavailable", "UnknownSetting", "build_settings", "endpoint_config", "load_service", "open_session",
    "parse_overrides", "read_config_file", "run_service", "setup_logging", "zenoh_config",
]
