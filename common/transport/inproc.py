"""The in-process transport: the `Transport` interface without a network, for `transport=inproc` runs and tests.

Every `InprocTransport` built on the same `Bus` sees the others' puts, latest values and
liveliness tokens, with the same semantics as the Zenoh transport: puts land in each matching
subscriber's bounded inbox (full: counted and dropped), `fetch` answers from a matching
`serve_latest`, tokens appear and disappear for watchers. A transport built without a bus
gets a private one, so `gvf-train transport=inproc` creates one `Bus` and hands it to every role.
"""

from __future__ import annotations

import threading
from collections import Counter

from common.config.transport import TransportConfig
from common.keys import key_matches
from common.transport.interface import AliveWatcher, LatestValue, Received, Subscription, Token, check_congestion
from common.wire import WireError


class Bus:
    """The shared 'network' of the in-process transports of one process."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._subs: list[Subscription] = []
        self._servers: list[LatestValue] = []
        self._tokens: Counter[str] = Counter()
        self._watchers: list[AliveWatcher] = []

    def deliver(self, key: str, payload: bytes) -> None:
        with self._lock:
            targets = [s for s in self._subs if key_matches(s.key_expr, key)]
        for sub in targets:
            sub.offer(Received(key, payload))

    def add_sub(self, sub: Subscription) -> None:
        with self._lock:
            self._subs.append(sub)

    def remove_sub(self, sub: Subscription) -> None:
        with self._lock:
            self._subs = [s for s in self._subs if s is not sub]

    def add_server(self, server: LatestValue) -> None:
        with self._lock:
            self._servers.append(server)

    def remove_server(self, server: LatestValue) -> None:
        with self._lock:
            self._servers = [s for s in self._servers if s is not server]

    def query(self, key_expr: str) -> bytes | None:
        with self._lock:
            servers = [s for s in self._servers if key_matches(key_expr, s.key)]
        for server in servers:
            payload = server.latest()
            if payload is not None:
                server.answered += 1
                return payload
            server.unanswered += 1
        return None

    def alive_keys(self, key_expr: str) -> set[str]:
        with self._lock:
            return {k for k, n in self._tokens.items() if n > 0 and key_matches(key_expr, k)}

    def _notify(self, key: str, alive: bool) -> None:
        with self._lock:
            watchers = [w for w in self._watchers if key_matches(w.key_expr, key)]
        for watcher in watchers:
            watcher.events.offer((key, alive))

    def add_token(self, key: str) -> None:
        with self._lock:
            self._tokens[key] += 1
            first = self._tokens[key] == 1
        if first:
            self._notify(key, True)

    def remove_token(self, key: str) -> None:
        with self._lock:
            self._tokens[key] -= 1
            last = self._tokens[key] == 0
            if last:
                del self._tokens[key]
        if last:
            self._notify(key, False)

    def add_watcher(self, watcher: AliveWatcher) -> None:
        with self._lock:
            self._watchers.append(watcher)
            present = [k for k, n in self._tokens.items() if n > 0 and key_matches(watcher.key_expr, k)]
        for key in present:
            watcher.events.offer((key, True))

    def remove_watcher(self, watcher: AliveWatcher) -> None:
        with self._lock:
            self._watchers = [w for w in self._watchers if w is not watcher]


class InprocPublisher:
    """Puts onto the bus; a full inbox counts a drop, as over Zenoh, after its `wait_s` (back-pressure)."""

    def __init__(self, bus: Bus, key: str, congestion: str, max_message_size: int) -> None:
        self.key = key
        self.congestion = congestion
        self._bus = bus
        self._max = max_message_size

    def put(self, payload: bytes) -> None:
        if len(payload) > self._max:
            raise WireError("size", f"{len(payload)} bytes > max_message_size {self._max}")
        self._bus.deliver(self.key, bytes(payload))

    def close(self) -> None:
        """Nothing to undeclare in-process; here for parity with the Zenoh publisher."""


class InprocTransport:
    """`Transport` over a `Bus` in this process."""

    def __init__(self, cfg: TransportConfig | None = None, bus: Bus | None = None) -> None:
        self.cfg = cfg or TransportConfig(backend="inproc")
        self.bus = bus if bus is not None else Bus()
        self._owned: list = []
        self._closed = False

    def _own(self, obj):
        if self._closed:
            raise RuntimeError("transport is closed")
        self._owned.append(obj)
        return obj

    def publisher(self, key: str, *, congestion: str = "block") -> InprocPublisher:
        return InprocPublisher(self.bus, key, check_congestion(congestion), self.cfg.max_message_size)

    def subscribe(
        self, key_expr: str, *, capacity: int | None = None, overflow: str = "drop_new", wait_s: float = 0.0
    ) -> Subscription:
        sub = self._own(Subscription(key_expr, capacity or self.cfg.inbox_capacity, overflow, wait_s))
        self.bus.add_sub(sub)
        sub._on_close = lambda: self.bus.remove_sub(sub)
        return sub

    def serve_latest(self, key: str) -> LatestValue:
        server = self._own(LatestValue(key))
        self.bus.add_server(server)
        server._on_close = lambda: self.bus.remove_server(server)
        return server

    def fetch(self, key: str, *, timeout: float | None = None) -> bytes | None:
        return self.bus.query(key)

    def declare_alive(self, key: str) -> Token:
        token = self._own(Token(key, lambda: self.bus.remove_token(key)))
        self.bus.add_token(key)
        return token

    def watch_alive(self, key_expr: str) -> AliveWatcher:
        watcher = self._own(AliveWatcher(key_expr, resync=lambda: self.bus.alive_keys(key_expr)))
        self.bus.add_watcher(watcher)
        watcher._on_close = lambda: self.bus.remove_watcher(watcher)
        return watcher

    def close(self) -> None:
        self._closed = True
        owned, self._owned = self._owned, []
        for obj in reversed(owned):
            obj.close()

    def __enter__(self) -> "InprocTransport":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
