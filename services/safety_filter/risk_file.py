"""Loading and watching the risk configuration file (node side: this is the only file I/O).

The file is a ``RiskConfig`` as YAML, TOML or JSON, either at the top level or under a
``risk:`` key. Labels may be given as ADE20K class names as well as indices::

    groups:
      - {name: high, labels: [person, animal], margin: 0.15, alpha: 0.6, alpha1: 1.2, alpha2: 0.36}
      - {name: low, labels: [wall, ball], margin: 0.0, alpha: 1.5}
    default_group: low
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from riskfield.protocol import RiskConfig, ade20k

from ..runtime.settings import read_config_file


def _label(value: Any) -> Any:
    if not isinstance(value, str):
        return value
    try:
        return ade20k.index(value)
    except KeyError as exc:
        raise ValueError(str(exc)) from None


def load_risk_file(path: str | Path) -> RiskConfig:
    """Parse and validate a risk file; raises ``FileNotFoundError`` or ``ValueError`` (incl.
    pydantic's ``ValidationError`` and unknown class names)."""
    try:
        data = read_config_file(path)
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: {exc}") from None
    if isinstance(data.get("risk"), dict):
        data = data["risk"]
    data = dict(data)
    if isinstance(data.get("groups"), list):
        data["groups"] = [
            {**g, "labels": [_label(x) for x in g.get("labels", [])]} if isinstance(g, dict) else g
            for g in data["groups"]
        ]
    if isinstance(data.get("free_labels"), list):
        data["free_labels"] = [_label(x) for x in data["free_labels"]]
    return RiskConfig.model_validate(data)


class RiskFileWatcher:
    """Reports a new ``RiskConfig`` when the file's modification time or size changes."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._seen: tuple[int, int] | None = None

    def poll(self) -> RiskConfig | None:
        """The new configuration if the file changed since the last call, else None. A file
        that changed but does not load raises (and is not retried until it changes again)."""
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return None
        sig = (st.st_mtime_ns, st.st_size)
        if sig == self._seen:
            return None
        self._seen = sig
        return load_risk_file(self.path)
