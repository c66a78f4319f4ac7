"""The one risk-file loader and watcher, shared by mapping and the safety filter (setting
``risk_file``; this is the only risk-file I/O).

The file is a ``RiskConfig`` as YAML, TOML or JSON, either at the top level or under a
``risk:`` key. Labels may be given as ADE20K class names as well as indices; keys that are
omitted take ``RiskConfig``'s defaults::

    groups:
      - {name: high, labels: [person, animal], margin: 0.15, alpha: 0.6, alpha1: 1.2, alpha2: 0.36}
      - {name: low, labels: [wall, ball], margin: 0.0, alpha: 1.5}
    default_group: low

The file is stricter than the wire message (which ignores unknown fields for compatibility):
a file that is empty, does not parse, has a key that is not a ``RiskConfig`` / ``RiskGroup``
field, or fails validation is a ``RiskFileError``. Hot reload (``watch_risk_file``) then keeps
the configuration in force, logs one error naming the problem and counts it, because falling
back to the defaults would silently shrink a margin the user had widened.
"""

from __future__ import annotations

import difflib
import json
import logging
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from pydantic import BaseModel, Field, ValidationError

from riskfield.protocol import RiskConfig, ade20k
from riskfield.protocol.risk import RiskGroup

from .settings import read_config_file

if TYPE_CHECKING:
    from .node import Node

#: Counters a watched risk file adds to the node's ``NodeStatus.extra``.
RELOADS, ERRORS = "risk_reloads", "risk_errors"


class RiskFileError(ValueError):
    """A risk file that cannot be used; the message names the file and the problem."""


def _label(value: Any) -> Any:
    if not isinstance(value, str):
        return value
    try:
        return ade20k.index(value)
    except KeyError as exc:
        close = difflib.get_close_matches(value, list(ade20k.INDEX), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"{exc.args[0]}{hint}") from None


def _check_keys(data: Mapping[str, Any], allowed: set[str], where: str) -> None:
    for key in data:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), sorted(allowed), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"unknown key {key!r} {where}{hint}")


def parse_risk(data: Mapping[str, Any]) -> RiskConfig:
    """A ``RiskConfig`` from a parsed file: unknown keys refused, class names turned into labels."""
    if isinstance(data.get("risk"), Mapping) and len(data) == 1:
        data = data["risk"]
    if not data:
        raise ValueError("the file is empty (no risk groups): refusing to fall back to the defaults")
    _check_keys(data, set(RiskConfig.model_fields) - {"header"}, "in the risk configuration")
    out = dict(data)
    if isinstance(out.get("groups"), list):
        groups = []
        for i, g in enumerate(out["groups"]):
            if isinstance(g, Mapping):
                _check_keys(g, set(RiskGroup.model_fields), f"in risk group {i}")
                g = {**g, "labels": [_label(x) for x in g.get("labels") or []]}
            groups.append(g)
        out["groups"] = groups
    if isinstance(out.get("free_labels"), list):
        out["free_labels"] = [_label(x) for x in out["free_labels"]]
    return RiskConfig.model_validate(out)


def load_risk_file(path: str | Path) -> RiskConfig:
    """Parse and validate a risk file; ``FileNotFoundError`` or ``RiskFileError``."""
    try:
        return parse_risk(read_config_file(path))
    except FileNotFoundError:
        raise
    except (ValueError, ValidationError, yaml.YAMLError, TypeError) as exc:  # tomllib's error is a ValueError
        text = str(exc).replace("\n", "; ")
        raise RiskFileError(f"risk file {path}: {text}") from None


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


class RiskFileReloader:
    """Hot reload of a watched risk file: ``poll()`` applies each valid change with ``apply``.

    A change that is empty, truncated, unknown-keyed or invalid, or that ``apply`` refuses with
    ``ValueError``, keeps the configuration in force: one error line naming the problem and
    one count in ``stats["risk_errors"]``; ``stats["risk_reloads"]`` counts what was applied.
    """

    def __init__(self, path: str | Path, apply: Callable[[RiskConfig], None], log: logging.Logger,
                 stats: dict[str, float]):
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"risk file {self.path} does not exist")
        self._watcher = RiskFileWatcher(self.path)
        self._apply, self._log, self.stats = apply, log, stats
        stats.setdefault(RELOADS, 0.0)
        stats.setdefault(ERRORS, 0.0)
        first = self._watcher.poll()  # a bad file at start raises: a configuration error
        assert first is not None
        self.initial: RiskConfig = first

    def poll(self) -> RiskConfig | None:
        """The configuration applied by this call, if any."""
        try:
            risk = self._watcher.poll()
            if risk is None:
                return None
            self._apply(risk)
        except (ValueError, OSError) as exc:
            self.stats[ERRORS] += 1
            self._log.error("%s not loaded, keeping the configuration in force: %s", self.path, exc)
            return None
        self.stats[RELOADS] += 1
        self._log.info("risk configuration reloaded from %s: groups %s", self.path, ", ".join(risk.group_names))
        return risk


def watch_risk_file(node: Node, path: str | Path, period_s: float,
                    apply: Callable[[RiskConfig], None]) -> RiskConfig:
    """Load ``path`` now (a bad file raises), poll it every ``period_s`` on the node's loop
    with a ``RiskFileReloader`` counting into the node's status; the configuration loaded now."""
    reloader = RiskFileReloader(path, apply, node.log, node.stats)

    def poll_risk_file() -> None:
        reloader.poll()

    node.every(period_s, poll_risk_file)
    return reloader.initial


class RiskStateSettings(BaseModel):
    """Where a node that uses a risk configuration keeps the one in force (``RiskStore``)."""

    state_dir: Path | None = Field(default=None, description=(
        "directory where the node keeps what must survive a restart: the risk configuration in force "
        "with its version (risk-<service>.json, reloaded at start); unset: nothing is kept, a restart "
        "starts from the built-in defaults (or risk_file) at version 0"))


class RiskStore:
    """The risk configuration in force, its version and digest, kept under a node's ``state_dir``.

    The version counts the changes this node took (0: the built-in defaults, never changed); a
    configuration with the digest of the one in force changes nothing. With a ``state_dir`` every
    change is written (atomically, readable by the service's user only) to
    ``<state_dir>/risk-<service>.json`` and reloaded by the next start, so a restart neither loses
    a configuration set over the wire nor reports a different version for it. A state file that
    does not load is a ``RiskFileError`` at start: the node refuses to guess what was in force.
    """

    def __init__(self, state_dir: str | Path | None, service: str, log: logging.Logger | None = None):
        self.path = None if state_dir is None else Path(state_dir) / f"risk-{service}.json"
        self.log = log or logging.getLogger(__name__)
        self.version = 0
        self.risk = RiskConfig()
        if self.path is not None and self.path.exists():
            try:
                data = json.loads(self.path.read_text())
                self.risk = RiskConfig.model_validate(data["config"])
                self.version = int(data["version"])
                if self.version < 0:
                    raise ValueError(f"version {self.version} is negative")
            except (OSError, ValueError, KeyError, TypeError) as exc:  # a ValidationError is a ValueError
                text = str(exc).replace("\n", "; ")
                raise RiskFileError(f"risk state {self.path}: {text}") from None
        self.digest = self.risk.digest()
        if self.version:
            self.log.info("risk configuration v%d %s reloaded from %s: groups %s", self.version, self.digest,
                          self.path, ", ".join(self.risk.group_names))

    def commit(self, risk: RiskConfig, origin: str) -> bool:
        """``risk`` is now in force (the caller applied it): a new version, kept, and one log line
        naming where it came from and what the floor kept (``RiskConfig.below_floor``). False when
        it is the configuration already in force."""
        digest = risk.digest()
        if digest == self.digest:
            return False
        self.risk, self.version, self.digest = risk, self.version + 1, digest
        if self.path is not None:
            self._write()
        lifted = risk.below_floor()
        floor = f"; {len(lifted)} label(s) it leaves free stay obstacles of {risk.group_names[-1]!r} (the floor)" \
            if lifted else ""
        self.log.info("risk configuration v%d %s from %s: groups %s%s", self.version, digest, origin,
                      ", ".join(risk.group_names), floor)
        return True

    def _write(self) -> None:
        assert self.path is not None
        self.path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        body = json.dumps({"version": self.version, "digest": self.digest,
                           "config": self.risk.model_dump(mode="json", exclude={"header"})})
        fd, tmp = tempfile.mkstemp(prefix=".risk-", dir=self.path.parent)  # mode 0600
        try:
            with os.fdopen(fd, "w") as f:
                f.write(body)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)  # a crash leaves the old file or the new one, never half of one
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise


__all__ = ["RiskFileError", "RiskFileReloader", "RiskFileWatcher", "RiskStateSettings", "RiskStore",
           "load_risk_file", "parse_risk", "watch_risk_file"]
