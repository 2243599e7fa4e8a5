"""The transport interface between actors, learner and launcher, and what implementations share.

`Transport` is the one interface; `common.transport.zenoh_backend.ZenohTransport` (real network) and
`common.transport.inproc.InprocTransport` (one process: `transport=inproc`, fast tests) implement it,
and `common.transport.make_transport(cfg)` picks one from `TransportConfig.backend`. Payloads are bytes (the
messages of `common.wire`); keys come from `common.keys`. The loops it serves:

    # actor (cfg: the run's config; cfg.transport a TransportConfig)
    keys = Keys(cfg.run)
    with make_transport(cfg.transport) as t:
        t.declare_alive(keys.alive("actor", name))
        weights_in = t.subscribe(keys.weights, capacity=1, overflow="drop_old")
        chunks_out = t.publisher(keys.transitions(name))          # congestion control BLOCK
        latest = t.fetch(keys.weights)                             # None until the learner answers
        while running:
            if (r := weights_in.get(timeout=0)) is not None: latest = r.payload
            ... step the envs ...; chunks_out.put(wire.encode(chunk))

    # learner
    rejects = wire.RejectCounter()
    with make_transport(cfg.transport) as t:
        chunks_in = t.subscribe(keys.all_transitions, capacity=4096)
        weights_out, weights_srv = t.publisher(keys.weights), t.serve_latest(keys.weights)
        actors = t.watch_alive(keys.all_alive("actor"))
        while running:
            for r in chunks_in.drain(256):           # bad payloads: counted, logged once per kind
                if (chunk := rejects.decode(r.payload, expect=TransitionChunk, key=r.key)): insert(chunk)
            ... train ...
            payload = wire.encode(weights); weights_out.put(payload); weights_srv.update(payload)
            log(chunks_in.dropped, rejects.counts, actors.alive())

Receiving never runs user code on the transport's threads: a callback only pushes onto the
receiver's own bounded inbox (`common.transport.inbox`) and returns; the owner's loop drains it.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Callable, Protocol, runtime_checkable

from common.transport.inbox import BoundedInbox


@dataclass(frozen=True)
class Received:
    """One payload as it arrived: the concrete key it was put on and its bytes."""

    key: str
    payload: bytes


class Subscription(BoundedInbox[Received]):
    """The bounded inbox of one subscriber; `get`/`drain` from the owner's loop, `dropped` counts overflow."""

    def __init__(self, key_expr: str, capacity: int, overflow: str = "drop_new", wait_s: float = 0.0) -> None:
        super().__init__(capacity, overflow, wait_s)
        self.key_expr = key_expr
        self._on_close: Callable[[], None] | None = None

    def close(self) -> None:
        """Stop receiving (undeclare) and wake any waiting `get`."""
        undeclare, self._on_close = self._on_close, None
        if undeclare is not None:
            undeclare()
        super().close()


class LatestValue:
    """The latest payload of a key, answered to every `fetch` of that key (e.g. the weights)."""

    def __init__(self, key: str) -> None:
        self.key = key
        self._payload: bytes | None = None
        self._lock = threading.Lock()
        self.answered = 0
        """Queries answered with a payload."""
        self.unanswered = 0
        """Queries that came before any payload (or whose reply failed)."""
        self._on_close: Callable[[], None] | None = None

    def update(self, payload: bytes) -> None:
        with self._lock:
            self._payload = bytes(payload)

    def latest(self) -> bytes | None:
        with self._lock:
            return self._payload

    def close(self) -> None:
        on_close, self._on_close = self._on_close, None
        if on_close is not None:
            on_close()


class Token:
    """A liveliness token: its key is alive for watchers until `close` (or the process dies)."""

    def __init__(self, key: str, on_close: Callable[[], None]) -> None:
        self.key = key
        self._on_close: Callable[[], None] | None = on_close

    def close(self) -> None:
        on_close, self._on_close = self._on_close, None
        if on_close is not None:
            on_close()


class AliveWatcher:
    """Who is alive under a key expression, from liveliness events pushed onto a bounded inbox.

    `poll()` (from the owner's loop) applies the pending events and returns them; if events
    were dropped because the inbox overflowed, the set is rebuilt with `resync`.
    """

    def __init__(self, key_expr: str, capacity: int = 1024, resync: Callable[[], set[str]] | None = None) -> None:
        self.key_expr = key_expr
        self.events: BoundedInbox[tuple[str, bool]] = BoundedInbox(capacity)
        self._resync = resync
        self._alive: set[str] = set()
        self._dropped_seen = 0
        self._on_close: Callable[[], None] | None = None

    def poll(self) -> list[tuple[str, bool]]:
        """Apply and return the (key, alive) events since the last poll."""
        events = self.events.drain()
        for key, alive in events:
            if alive:
                self._alive.add(key)
            else:
                self._alive.discard(key)
        if self.events.dropped != self._dropped_seen and self._resync is not None:
            # some join/leave events were lost: ask the network who is alive now
            self._dropped_seen = self.events.dropped
            self._alive = set(self._resync())
        return events

    def alive(self) -> frozenset[str]:
        """Keys of the live tokens, up to date as of this call."""
        self.poll()
        return frozenset(self._alive)

    def close(self) -> None:
        on_close, self._on_close = self._on_close, None
        if on_close is not None:
            on_close()
        self.events.close()


class Publisher(Protocol):
    """Puts payloads on one key."""

    key: str

    def put(self, payload: bytes) -> None:
        """Send; with congestion control BLOCK waits for the network rather than dropping.

        Raises WireError('size') for a payload over `max_message_size` (Zenoh would drop it silently).
        """

    def close(self) -> None:
        """Undeclare (the transport's close does it too)."""


@runtime_checkable
class Transport(Protocol):
    """What actors, learner and launcher need from the network (see the module docstring)."""

    def publisher(self, key: str, *, congestion: str = "block") -> Publisher:
        """A publisher on concrete `key`; congestion 'block' (default) or 'drop'."""

    def subscribe(
        self, key_expr: str, *, capacity: int | None = None, overflow: str = "drop_new", wait_s: float = 0.0
    ) -> Subscription:
        """Start receiving puts matching `key_expr` into a bounded inbox of `capacity`; a put that finds it
        full waits up to `wait_s` for room (back-pressure on the sender under BLOCK), then `overflow` applies."""

    def serve_latest(self, key: str) -> LatestValue:
        """Answer `fetch(key)` from anywhere with the payload last given to `.update()`."""

    def fetch(self, key: str, *, timeout: float | None = None) -> bytes | None:
        """The payload a `serve_latest(key)` somewhere holds, or None if none answers in time."""

    def declare_alive(self, key: str) -> Token:
        """Announce this process as alive under `key` until the token is closed or the process dies."""

    def watch_alive(self, key_expr: str) -> AliveWatcher:
        """Track the live tokens matching `key_expr` (those already alive included)."""

    def close(self) -> None:
        """Undeclare everything and close the session; idempotent."""

    def __enter__(self) -> "Transport": ...

    def __exit__(self, *exc: object) -> None: ...


def check_congestion(congestion: str) -> str:
    if congestion not in ("block", "drop"):
        raise ValueError(f"congestion must be 'block' or 'drop', got {congestion!r}")
    return congestion
