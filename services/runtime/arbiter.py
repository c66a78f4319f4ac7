"""Arbitration of velocity commands from several sources, as ROS users get it from twist_mux.

The rules are twist_mux's (ros-teleop/twist_mux, read at 4.3.0):

* An input is *live* while its last message is no older than its timeout
  (``TopicHandle_::hasExpired`` in include/twist_mux/topic_handle.hpp: a timeout of 0 never
  expires). Every message renews its input's stamp, forwarded or not
  (``VelocityTopicHandle::callback`` stamps before it asks for priority).
* A message is forwarded iff its input is the highest-priority live input not masked by a lock
  (``TwistMux::hasPriority`` in src/twist_mux.cpp); among equal priorities the first declared wins
  (the strict ``priority < velocity_priority`` of that scan).
* A lock masks every input whose priority is below the lock's (``VelocityTopicHandle::isMasked``);
  a lock is on while its last message says so or, with a timeout, once its publisher has been
  silent longer than that (``LockTopicHandle::isLocked``): a dead lock publisher locks.

Where this differs, on purpose: an input never heard from is not live, whatever its timeout
(twist_mux starts every stamp at 0, so an input with timeout 0 would hold the lower ones before it
ever spoke); a message may decline to claim (``claims=False``: a joystick whose dead-man is
released, the way teleop_twist_joy stops publishing without its enable button): it renews nothing,
and is forwarded only while its input is the active one or no input is live at all, so the
release's zeros still reach the robot and an idle joystick alone still gives the filter a
reference; inputs and locks not declared can be admitted with default parameters (a source name
the deployment did not list). No I/O here: the caller passes a monotonic ``now``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

#: twist_mux clamps priorities to [0, 255] (``TopicHandle_``'s constructor).
MAX_PRIORITY = 255

#: Why ``CommandMux.admit`` refused a message.
UNKNOWN, PREEMPTED, LOCKED, IDLE = "unknown_source", "preempted", "locked", "idle"
#: Why a message never reached the arbitration: its key ``cmd/ref/<source>`` names another source
#: than the message declares, or it came on the plain key where that is not taken
#: (``protocol.keys.REF_SOURCES``: the key, not the message, is what the routers authenticate).
SOURCE_MISMATCH, PLAIN_KEY = "source_mismatch", "plain_key"


@dataclass
class MuxInput:
    """One velocity source: its name, priority (higher wins) and timeout (0: never expires)."""

    name: str
    priority: int
    timeout_s: float
    stamp: float = -math.inf

    def expired(self, now: float) -> bool:
        if self.stamp == -math.inf:
            return True
        return self.timeout_s > 0 and now - self.stamp > self.timeout_s


@dataclass
class MuxLock:
    """One lock source: on while its last message said so or, with a timeout, while it is silent."""

    name: str
    priority: int
    timeout_s: float
    stamp: float = -math.inf
    locked: bool = False

    def is_locked(self, now: float) -> bool:
        silent = self.timeout_s > 0 and now - self.stamp > self.timeout_s
        return silent or self.locked


class CommandMux:
    """Priority arbitration of velocity sources with locks (module doc).

    ``default_input`` / ``default_lock``: ``(priority, timeout_s)`` given to a source not declared,
    on its first message; ``None`` refuses undeclared velocity sources (``unknown_source``) or
    undeclared lock sources (their messages are ignored).
    """

    def __init__(self, inputs: Sequence[MuxInput], locks: Sequence[MuxLock] = (),
                 default_input: tuple[int, float] | None = None, default_lock: tuple[int, float] | None = None):
        self.inputs: dict[str, MuxInput] = {}
        for i in inputs:
            if i.name in self.inputs:
                raise ValueError(f"velocity source {i.name!r} is declared twice")
            self.inputs[i.name] = i
        self.locks: dict[str, MuxLock] = {}
        for lk in locks:
            if lk.name in self.locks:
                raise ValueError(f"lock source {lk.name!r} is declared twice")
            self.locks[lk.name] = lk
        self.default_input, self.default_lock = default_input, default_lock

    # -- inputs ---------------------------------------------------------------------------------
    def admit(self, name: str, now: float, claims: bool = True) -> str | None:
        """A message from source ``name`` at ``now``: None if it is to be forwarded, else why not
        (``unknown_source``, ``locked``, ``preempted``, ``idle``)."""
        source = self.inputs.get(name)
        if source is None:
            if self.default_input is None:
                return UNKNOWN
            source = self.inputs[name] = MuxInput(name, *self.default_input)
        if claims:
            source.stamp = now
        active = self.active(now)
        if active == name:
            return None
        if source.priority < self.lock_priority(now):
            return LOCKED
        if active is None:  # only a declining source gets here: nothing live to give way to
            return None
        return PREEMPTED if claims or not source.expired(now) else IDLE

    def lock(self, name: str, locked: bool, now: float) -> bool:
        """A lock message from ``name``; False if the source is not declared and has no default."""
        lk = self.locks.get(name)
        if lk is None:
            if self.default_lock is None:
                return False
            lk = self.locks[name] = MuxLock(name, *self.default_lock)
        lk.stamp, lk.locked = now, locked
        return True

    # -- queries --------------------------------------------------------------------------------
    def lock_priority(self, now: float) -> int:
        """The highest priority among the locks that are on; 0 when none is."""
        return max((lk.priority for lk in self.locks.values() if lk.is_locked(now)), default=0)

    def masked(self, name: str, now: float) -> bool:
        """Whether source ``name`` (declared or not) is below the priority of a lock that is on."""
        source = self.inputs.get(name)
        if source is not None:
            priority = source.priority
        elif self.default_input is not None:
            priority = self.default_input[0]
        else:
            return True
        return priority < self.lock_priority(now)

    def active(self, now: float) -> str | None:
        """The source whose messages are forwarded now: the highest-priority live input not
        masked by a lock (the first declared among equals), or None."""
        floor = self.lock_priority(now)
        best: MuxInput | None = None
        for i in self.inputs.values():
            if i.expired(now) or i.priority < floor:
                continue
            if best is None or i.priority > best.priority:
                best = i
        return None if best is None else best.name


__all__ = ["IDLE", "LOCKED", "MAX_PRIORITY", "PREEMPTED", "UNKNOWN", "CommandMux", "MuxInput", "MuxLock"]
