"""A receiver's own bounded queue: what transport callbacks push onto, and all they do.

A Zenoh callback must return at once (under congestion control BLOCK a subscriber stuck for
5 s is disconnected by the router), so `offer` never blocks: when the inbox is full it drops
(the new item, or the oldest one for "latest value wins" topics such as weights) and counts.
The owner's loop takes items with `get` or `drain` at its own pace.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Generic, TypeVar

T = TypeVar("T")

OVERFLOW_POLICIES = ("drop_new", "drop_old")


class BoundedInbox(Generic[T]):
    """Thread-safe bounded FIFO: non-blocking `offer` for producers, `get`/`drain` for the owner."""

    def __init__(self, capacity: int, overflow: str = "drop_new") -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        if overflow not in OVERFLOW_POLICIES:
            raise ValueError(f"overflow must be one of {OVERFLOW_POLICIES}, got {overflow!r}")
        self.capacity = capacity
        self.overflow = overflow
        self._items: deque[T] = deque()
        self._cond = threading.Condition()
        self._closed = False
        self.received = 0
        """Items offered, kept or not."""
        self.dropped = 0
        """Items dropped because the inbox was full (or closed)."""

    def offer(self, item: T) -> bool:
        """Push without blocking; False when `item` itself was dropped."""
        with self._cond:
            self.received += 1
            if self._closed:
                self.dropped += 1
                return False
            if len(self._items) >= self.capacity:
                self.dropped += 1
                if self.overflow == "drop_new":
                    return False
                self._items.popleft()
            self._items.append(item)
            self._cond.notify()
            return True

    def get(self, timeout: float | None = None) -> T | None:
        """The oldest item, waiting up to `timeout` seconds (None: forever); None if none came."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._items:
                if self._closed:
                    return None
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining)
            return self._items.popleft()

    def drain(self, max_items: int | None = None) -> list[T]:
        """Up to `max_items` items (all if None) without waiting."""
        with self._cond:
            n = len(self._items) if max_items is None else min(max_items, len(self._items))
            return [self._items.popleft() for _ in range(n)]

    def __len__(self) -> int:
        return len(self._items)

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Refuse further items and wake every waiting `get` (which then returns what is left, then None)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
