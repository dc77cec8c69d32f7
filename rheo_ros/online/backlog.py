"""A bounded work queue for a lane that may fall behind its input."""

from __future__ import annotations

import threading
from collections import deque
from typing import Callable, Generic, TypeVar

Item = TypeVar("Item")


class Backlog(Generic[Item]):
    """First in, first out, at most ``size`` items waiting: putting into a full backlog
    drops a waiting item and counts it. A lane slower than the
    pushes arriving (whole-record fits and diagnoses at a 10 x replay, or a robot probing
    faster than the fits run) then holds the newest work and bounded memory, not a queue
    that grows for as long as the node runs.

    ``supersedes(newer, older)``: when room is needed, a waiting item that a newer one
    makes pointless leaves first (counted in ``superseded``), the oldest only if there is
    none (``dropped``): a push's release fit covers the data its pull and keep fits would,
    so a lane behind the pushes spends itself on final estimates. A lane keeping up skips
    nothing.

    ``replaces(newer, older)``: a waiting item that a new one makes stale leaves at once,
    room or not (counted in ``replaced``): an interim release fit once a later stretch of
    its release waits, whose numbers nobody wants any more.
    """

    def __init__(self, size: int, supersedes: Callable[[Item, Item], bool] | None = None,
                 replaces: Callable[[Item, Item], bool] | None = None) -> None:
        if size < 1:
            raise ValueError(f"backlog size {size}: at least 1")
        self.size = size
        self.supersedes, self.replaces = supersedes, replaces
        self.dropped = 0
        self.superseded = 0
        self.replaced = 0
        self._items: deque[Item] = deque()
        self._ready = threading.Condition()

    def put(self, item: Item) -> None:
        with self._ready:
            if self.replaces is not None:
                kept = deque(old for old in self._items if not self.replaces(item, old))
                self.replaced += len(self._items) - len(kept)
                self._items = kept
            if len(self._items) >= self.size:
                victim = self._superseded(item)
                if victim is None:
                    self._items.popleft()
                    self.dropped += 1
                else:
                    del self._items[victim]
                    self.superseded += 1
            self._items.append(item)
            self._ready.notify()

    def _superseded(self, item: Item) -> int | None:
        """Index of the oldest waiting item that a newer one (or ``item``) supersedes."""
        if self.supersedes is None:
            return None
        waiting = list(self._items) + [item]
        for i, old in enumerate(waiting[:-1]):
            if any(self.supersedes(newer, old) for newer in waiting[i + 1:]):
                return i
        return None

    def get(self) -> Item:
        """The oldest waiting item; blocks until there is one."""
        with self._ready:
            while not self._items:
                self._ready.wait()
            return self._items.popleft()

    def holds(self, predicate: Callable[[Item], bool]) -> bool:
        """Whether a waiting item satisfies ``predicate``."""
        with self._ready:
            return any(predicate(item) for item in self._items)

    def __len__(self) -> int:
        with self._ready:
            return len(self._items)
