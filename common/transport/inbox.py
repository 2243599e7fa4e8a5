"""A receiver's own bounded queue: what transport callbacks push onto, and all they do.

A Zenoh callback must return soon (under congestion control BLOCK a link stuck for 5 s,
zenoh's `wait_before_close`, is closed), so `offer` waits at most `wait_s` (default 0: not at
all): when the inbox is still full it drops (the new item, or the oldest one for "latest value
wins" topics such as weights) and counts. A wait is back-pressure: the transport's thread stops
reading, so BLOCK publishers upstream slow down instead of their data being dropped here; but
every other message on that session waits with it (at 256 actors a learner waiting 1 s per chunk
starved its own weights and acks), so the learner keeps it off by default (`learner.inbox_wait_s`).
The owner's loop takes items with `get` or `drain` at its own pace.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Generic, TypeVar

from common.config.transport import ZENOH_WAIT_BEFORE_CLOSE_S

T = TypeVar("T")

OVERFLOW_POLICIES = ("drop_new", "drop_old")


class BoundedInbox(Generic[T]):
    """Thread-safe bounded FIFO: `offer` (waits at most `wait_s`) for producers, `get`/`drain` for the owner."""

    def __init__(self, capacity: int, overflow: str = "drop_new", wait_s: float = 0.0) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        if overflow not in OVERFLOW_POLICIES:
            raise ValueError(f"overflow must be one of {OVERFLOW_POLICIES}, got {overflow!r}")
        if not 0.0 <= wait_s < ZENOH_WAIT_BEFORE_CLOSE_S:
            raise ValueError(
                f"wait_s must be in [0, {ZENOH_WAIT_BEFORE_CLOSE_S}) (zenoh closes a link blocked that long), got {wait_s}"
            )
        self.capacity = capacity
        self.overflow = overflow
        self.wait_s = wait_s
        self._items: deque[T] = deque()
        lock = threading.Lock()
        self._cond = threading.Condition(lock)  # the owner waits for items
        self._room = threading.Condition(lock)  # producers wait for space (wait_s > 0)
        self._closed = False
        self.received = 0
        """Items offered, kept or not."""
        self.dropped = 0
        """Items dropped because the inbox was full (or closed)."""
        self.waited = 0
        """Offers that found the inbox full and waited for room (kept or, after `wait_s`, dropped)."""

    def offer(self, item: T) -> bool:
        """Push, waiting up to `wait_s` for room; False when `item` itself was dropped."""
        with self._cond:
            self.received += 1
            if self._closed:
                self.dropped += 1
                return False
            if len(self._items) >= self.capacity and self.wait_s > 0:
                self.waited += 1
                deadline = time.monotonic() + self.wait_s
                while len(self._items) >= self.capacity and not self._closed:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        break
                    self._room.wait(remaining)
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
            self._room.notify()
            return self._items.popleft()

    def drain(self, max_items: int | None = None) -> list[T]:
        """Up to `max_items` items (all if None) without waiting."""
        with self._cond:
            n = len(self._items) if max_items is None else min(max_items, len(self._items))
            if n:
                self._room.notify(n)
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
            self._room.notify_all()
