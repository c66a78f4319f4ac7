"""The node's inbox: Zenoh callbacks drop raw samples into slots, one loop thread takes
them out. A ``latest`` slot keeps only the newest item (a slow consumer skips stale data
instead of building a backlog); a ``fifo`` slot keeps every item up to ``maxlen`` and, with
``max_bytes``, up to that many payload bytes (each item counts its size plus ``ITEM_OVERHEAD``),
dropping the oldest and counting the drops. Slots are served round-robin so one busy stream cannot starve another.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Literal

QueueKind = Literal["latest", "fifo"]

#: Bytes an item counts beyond its payload in a byte-bounded slot: the tuple, the bytes object and
#: the deque cell, so a flood of empty samples is bounded too.
ITEM_OVERHEAD = 256


@dataclass(eq=False)
class Slot:
    name: str
    kind: QueueKind
    maxlen: int = 1
    max_bytes: int = 0  # 0: bounded by maxlen only
    items: deque = field(default_factory=deque)
    received: int = 0
    dropped: int = 0
    nbytes: int = 0  # what the queued items count against max_bytes
    queued: bool = False  # whether the slot sits in the ready queue
    owner: Any = None  # whom the loop hands its items to (the node's subscription)


class Inbox:
    def __init__(self) -> None:
        self._cv = threading.Condition()
        self._ready: deque[Slot] = deque()
        self._closed = False

    def slot(self, name: str, kind: QueueKind = "latest", maxlen: int = 1000, max_bytes: int = 0) -> Slot:
        return Slot(name=name, kind=kind, maxlen=1 if kind == "latest" else max(1, maxlen),
                    max_bytes=0 if kind == "latest" else max(0, max_bytes))

    def put(self, slot: Slot, item: Any, size: int = 0) -> None:
        """Queue ``item``; ``size`` (its payload bytes) counts against the slot's ``max_bytes``."""
        cost = size + ITEM_OVERHEAD if slot.max_bytes else 0
        with self._cv:
            slot.received += 1
            if cost > slot.max_bytes > 0:  # alone over the bound: never queued
                slot.dropped += 1
                return
            while slot.items and (len(slot.items) >= slot.maxlen or slot.nbytes + cost > slot.max_bytes > 0):
                _, old_cost = slot.items.popleft()
                slot.nbytes -= old_cost
                slot.dropped += 1
            slot.items.append((item, cost))
            slot.nbytes += cost
            if not slot.queued:
                slot.queued = True
                self._ready.append(slot)
            self._cv.notify()

    def get(self, timeout: float | None) -> tuple[Slot, Any] | None:
        """Next item, round-robin over slots; ``None`` on timeout or when woken empty."""
        with self._cv:
            if not self._ready and not self._closed:
                self._cv.wait(timeout)
            if not self._ready:
                return None
            slot = self._ready.popleft()
            item, cost = slot.items.popleft()
            slot.nbytes -= cost
            if slot.items:
                self._ready.append(slot)
            else:
                slot.queued = False
            return slot, item

    def wake(self) -> None:
        with self._cv:
            self._cv.notify_all()

    def close(self) -> None:
        with self._cv:
            self._closed = True
            self._cv.notify_all()
