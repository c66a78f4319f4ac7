"""The node's inbox: Zenoh callbacks drop raw samples into slots, one loop thread takes
them out. A ``latest`` slot keeps only the newest item (a slow consumer skips stale data
instead of building a backlog); a ``fifo`` slot keeps every item up to ``maxlen`` and
counts overflow. Slots are served round-robin so one busy stream cannot starve another.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Literal

QueueKind = Literal["latest", "fifo"]


@dataclass(eq=False)
class Slot:
    name: str
    kind: QueueKind
    maxlen: int = 1
    items: deque = field(default_factory=deque)
    received: int = 0
    dropped: int = 0
    queued: bool = False  # whether the slot sits in the ready queue


class Inbox:
    def __init__(self) -> None:
        self._cv = threading.Condition()
        self._ready: deque[Slot] = deque()
        self._closed = False

    def slot(self, name: str, kind: QueueKind = "latest", maxlen: int = 1000) -> Slot:
        return Slot(name=name, kind=kind, maxlen=1 if kind == "latest" else max(1, maxlen))

    def put(self, slot: Slot, item: Any) -> None:
        with self._cv:
            slot.received += 1
            if len(slot.items) >= slot.maxlen:
                slot.items.popleft()
                slot.dropped += 1
            slot.items.append(item)
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
            item = slot.items.popleft()
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
