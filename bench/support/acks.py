"""Weight-broadcast acks of bench/scale.py in constant memory: a latency histogram and the acks
of the broadcasts still in flight. Keeping every (actor, version) arrival grew the learner
process by ~28 MB in a 10-minute run at 256 actors (2 broadcasts/s), which is the benchmark's
own bookkeeping, not the learner's; a memory run must not measure itself."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

BIN_MS = 0.1
"""Histogram resolution: percentiles are exact to this many ms."""
SPAN_MS = 60_000.0
"""Latencies beyond this are kept exactly (rare: a stalled link)."""


class Latencies:
    """Milliseconds in fixed-width bins (numpy has no streaming percentile)."""

    def __init__(self) -> None:
        self.bins = np.zeros(int(SPAN_MS / BIN_MS) + 1, np.int64)
        self.beyond: list[float] = []
        self.count = 0

    def add(self, ms: float) -> None:
        self.count += 1
        if 0.0 <= ms < SPAN_MS:
            self.bins[int(ms / BIN_MS)] += 1
        else:
            self.beyond.append(ms)

    def merge(self, other: Latencies) -> Latencies:
        out = Latencies()
        out.bins = self.bins + other.bins
        out.beyond = self.beyond + other.beyond
        out.count = self.count + other.count
        return out

    def percentile(self, p: float) -> float | None:
        """The value at or below which p% of the latencies lie, to BIN_MS (nearest rank)."""
        if not self.count:
            return None
        rank = max(1, int(np.ceil(p / 100.0 * self.count)))
        low = [x for x in self.beyond if x < 0.0]
        if rank <= len(low):
            return float(sorted(low)[rank - 1])
        rank -= len(low)
        cumulative = np.cumsum(self.bins)
        if rank <= cumulative[-1]:
            return float((np.searchsorted(cumulative, rank) + 0.5) * BIN_MS)
        return float(sorted(x for x in self.beyond if x >= SPAN_MS)[rank - cumulative[-1] - 1])


@dataclass
class _Pending:
    at: float
    """time.time() just before the put."""
    heard: set[str] = field(default_factory=set)
    last: float = 0.0
    """The latest arrival so far."""


class Acks:
    """The acks of one phase: each (actor, version) arrival becomes a latency at once; a version
    is forgotten when every actor acked it, or counted as missed at `close`."""

    def __init__(self, names: list[str]) -> None:
        self.n = len(names)
        self.pending: dict[int, _Pending] = {}
        self.each, self.to_all = Latencies(), Latencies()
        self.missed = 0

    def published(self, version: int, at: float) -> None:
        self.pending[version] = _Pending(at, last=at)

    def add(self, name: str, version: int, arrived: float) -> None:
        p = self.pending.get(version)
        if p is None or name in p.heard:
            return  # a version of another phase, or a repeated ack
        p.heard.add(name)
        self.each.add((arrived - p.at) * 1e3)
        p.last = max(p.last, arrived)
        if len(p.heard) == self.n:
            self.to_all.add((p.last - p.at) * 1e3)
            del self.pending[version]

    @property
    def waiting(self) -> bool:
        return bool(self.pending)

    def close(self) -> None:
        self.missed += sum(self.n - len(p.heard) for p in self.pending.values())
        self.pending.clear()
