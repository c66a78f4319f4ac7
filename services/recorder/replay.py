"""Replay planning: remaps of whole key prefixes, command keys withheld, and the schedule.

A replay must never drive a live robot by accident: command keys (``cmd/safe``, ``cmd/ref``,
``cmd/lock``, ``nav/goal``) are withheld unless asked for, and so is the robot's ``state`` (``state``,
``state/relocalise``): a recorded state put beside a live robot's moves its mapping volume and
feeds its filter a position the robot is not at. A remap rewrites a whole key prefix or is refused
(no wildcards, no empty chunks, a trailing slash is normalised), and a remap that matches no
recorded key is an error instead of a silent replay onto the original keys.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from .mcap_io import KeyInfo, Record

#: Keys (relative to a robot root) that move a robot; replayed only with ``include_commands``.
COMMAND_KEYS = ("cmd/safe", "cmd/ref", "cmd/lock", "nav/goal")  # a replayed unlock would release a live lock
# the key chunk alphabet of riskfield.protocol.keys, without the wildcard-forming `*` and `$`
_CHUNK = re.compile(r"^[A-Za-z0-9_\-.~+=@:]+$")


#: Keys (relative to a robot root) that say where the robot is; replayed only with ``include_state``.
STATE_KEYS = ("state", "state/relocalise")


def is_command(key: str) -> bool:
    # A command key anywhere in the key, not only at its end: cmd/ref/<source> and
    # cmd/lock/<source> are commands too (protocol.keys.SOURCED). Withholding too much is safe.
    return any(f"/{c}/" in f"/{key}/" for c in COMMAND_KEYS)


def is_state(key: str) -> bool:
    return any(key == c or key.endswith("/" + c) for c in STATE_KEYS)


def _prefix(value: str, what: str) -> str:
    v = value.strip()
    if v.endswith("/"):
        v = v[:-1]  # `rf/limo1/` means the prefix rf/limo1
    if not v:
        raise ValueError(f"{what} is empty")
    if "*" in v or "$" in v:
        raise ValueError(f"{what} {value!r} has a wildcard: a remap takes one concrete key prefix")
    for chunk in v.split("/"):
        if not _CHUNK.match(chunk):
            raise ValueError(f"{what} {value!r}: chunks use letters, digits and -_.~+=@: (no empty chunks)")
    return v


@dataclass(frozen=True)
class Remap:
    """Rewrites ``{old_root}/...`` keys to ``{new_root}/...`` (another robot id or prefix)."""

    old_root: str | None = None
    new_root: str | None = None

    def __post_init__(self) -> None:
        if (self.old_root is None) != (self.new_root is None):
            raise ValueError("give both remap_from and remap_to, or neither")
        if self.old_root is not None and self.new_root is not None:
            object.__setattr__(self, "old_root", _prefix(self.old_root, "remap_from"))
            object.__setattr__(self, "new_root", _prefix(self.new_root, "remap_to"))

    @property
    def active(self) -> bool:
        return self.old_root is not None

    def matches(self, key: str) -> bool:
        return self.old_root is not None and (key == self.old_root or key.startswith(self.old_root + "/"))

    def __call__(self, key: str) -> str:
        if self.old_root is not None and self.new_root is not None and self.matches(key):
            return self.new_root + key[len(self.old_root):]
        return key


@dataclass
class Plan:
    """What a replay of a recording publishes, withholds and cannot reproduce, per recorded key."""

    publish: dict[str, tuple[str, int]] = field(default_factory=dict)  # key → (published as, raw messages)
    withheld: list[str] = field(default_factory=list)  # command keys without include_commands
    withheld_state: list[str] = field(default_factory=list)  # state keys without include_state
    status: list[str] = field(default_factory=list)  # node statuses of the recorded run (never replayed)
    not_reproducible: list[str] = field(default_factory=list)  # recorded only as views

    def lines(self) -> list[str]:
        out = [f"publish   {k} → {to}  ({n} messages)" if to != k else f"publish   {k}  ({n} messages)"
               for k, (to, n) in sorted(self.publish.items())]
        out += [f"withheld  {k}  (a command key: --include-commands to publish it)" for k in sorted(self.withheld)]
        out += [f"withheld  {k}  (the robot's state: --include-state to publish it)"
                for k in sorted(self.withheld_state)]
        out += [f"skipped   {k}  (node status of the recorded run)" for k in sorted(self.status)]
        out += [f"cannot    {k}  (recorded only as a view: record with --raw to replay it)"
                for k in sorted(self.not_reproducible)]
        return out


def is_status(key: str) -> bool:
    return "/status/" in key


def plan(keys: dict[str, KeyInfo], remap: Remap, *, include_commands: bool = False,
         skip_status: bool = True, include_state: bool = False) -> Plan:
    """The replay plan of a scanned recording; a remap that matches no recorded key is an error."""
    p = Plan()
    raw = {k: i for k, i in keys.items() if i.raw}
    if remap.active and not any(remap.matches(k) for k in raw):
        known = sorted({"/".join(k.split("/")[:2]) for k in raw})
        raise ValueError(f"remap_from {remap.old_root!r} matches no recorded key (recorded roots: "
                         f"{', '.join(known) or 'none'})")
    for k, info in keys.items():
        if not info.raw:
            if info.views and _is_key_view(k, keys) and not (skip_status and is_status(k)):
                p.not_reproducible.append(k)
        elif skip_status and is_status(k):
            p.status.append(k)
        elif is_command(k) and not include_commands:
            p.withheld.append(k)
        elif is_state(k) and not include_state:
            p.withheld_state.append(k)
        else:
            p.publish[k] = (remap(k), info.raw)
    return p


def _is_key_view(topic: str, keys: dict[str, KeyInfo]) -> bool:
    # the robot's `{root}/tf` is a derived view of `{root}/state`, not a key of its own
    return not (topic.endswith("/tf") and topic[:-3] + "/state" in keys)


def schedule(records: Iterable[Record], speed: float = 1.0) -> Iterator[tuple[float, Record]]:
    """(seconds after the start at which to publish, record), keeping the recorded spacing / speed."""
    if speed <= 0:
        raise ValueError("speed must be > 0")
    t0 = None
    for rec in records:
        if t0 is None:
            t0 = rec.log_time_ns
        yield (rec.log_time_ns - t0) / 1e9 / speed, rec
