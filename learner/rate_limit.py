"""The learner's rate limit as arithmetic alone: how many updates the samples-per-insert ratio
allows now, and whether the actors should pause (no clock, no transport: unit-tested on counts).

One update samples `batch` transitions, so under a ratio of `samples_per_insert` it consumes
`batch / samples_per_insert` inserted transitions. Once the warm-up is met (at `inserted` =
`ready_at`), the updates owed are 1 + floor(surplus / per_update), where surplus = inserted -
ready_at - done * per_update. The actors are asked to pause while the data ahead of the updates
(surplus plus what waits in the inbox; before the warm-up, the replay beyond it) exceeds
`max_owed_updates` updates' worth, and to resume once it is within half of that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class RateLimiter:
    batch_size: int
    samples_per_insert: float
    max_owed_updates: int = 0
    """0: never pause the actors."""
    ready_at: int | None = None
    """Transitions inserted when the warm-up was met (None before)."""
    done: int = 0
    """Updates done since then, in this learner's life (a resumed learner starts at 0)."""
    paused: bool = False

    def __post_init__(self) -> None:
        if self.samples_per_insert <= 0:
            raise ValueError(f"learner.samples_per_insert must be > 0, got {self.samples_per_insert}")
        if self.max_owed_updates < 0:
            raise ValueError(f"learner.max_owed_updates must be >= 0, got {self.max_owed_updates}")

    @property
    def per_update(self) -> float:
        """Inserted transitions one update consumes."""
        return self.batch_size / self.samples_per_insert

    def owed(self, inserted: int, ready: bool) -> int:
        """Updates allowed now and not yet done (0 before the warm-up is met)."""
        if not ready:
            return 0
        if self.ready_at is None:
            self.ready_at = inserted
        return max(0, 1 + math.floor(self.surplus(inserted) / self.per_update))

    def surplus(self, inserted: int) -> float:
        """Transitions inserted since the warm-up beyond those the updates done consumed."""
        return inserted - (self.ready_at or 0) - self.done * self.per_update

    def ahead(self, inserted: int, waiting: int, replay: int, warmup: int) -> float:
        """Transitions held (inserted or `waiting` in the inbox) beyond what the learner needs now:
        before the warm-up is met the replay beyond it, then the surplus."""
        if self.ready_at is None:  # the replay, not the counters: a resumed learner may start empty
            return replay + waiting - max(warmup, 1)
        return self.surplus(inserted) + waiting

    def should_pause(self, ahead: float) -> bool:
        """Pause above the limit; once paused, stay paused until within half of it."""
        if not self.max_owed_updates:
            return False
        limit = self.max_owed_updates * self.per_update
        self.paused = ahead > limit or (self.paused and ahead > limit / 2)
        return self.paused
