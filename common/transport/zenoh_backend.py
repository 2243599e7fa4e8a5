"""The Zenoh implementation of `common.transport.Transport`, its config, and the run's router.

Facts this module is built on (checked with eclipse-zenoh 1.10.2, see DESIGN.md):
- a publisher's default congestion control is DROP (puts vanish under load): ours default to BLOCK;
- under BLOCK a subscriber stuck for 5 s is disconnected, so callbacks only push onto the
  receiver's own bounded inbox and return; they never call zenoh (queries are answered by a
  server thread, not in the callback);
- callbacks run with `indirect=False`, on Zenoh's own thread: the default (`indirect=True`)
  runs them on a non-daemon Python thread that the interpreter waits for at exit, so a
  session left open hung the process; with `indirect=False` it exits (a test checks this).
  Close sessions anyway: `with ZenohTransport(cfg) as t:`;
- a payload over `transport/link/rx/max_message_size` is dropped silently: publishers refuse
  it with `WireError('size')` instead;
- forking after zenoh is initialised hangs the child: start processes with 'spawn'.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import signal
import threading
from typing import Any, Callable

import zenoh

from common.config.transport import TransportConfig
from common.keys import route_of_key
from common.transport.inbox import BoundedInbox
from common.transport.interface import AliveWatcher, LatestValue, Received, Subscription, Token, check_congestion
from common.wire import WireError

log = logging.getLogger(__name__)

MODES = ("peer", "client", "router")
QUERY_BACKLOG = 64
"""Queries for a latest value waiting for the server thread; more are dropped (unanswered)."""


def zenoh_config(
    cfg: TransportConfig, *, mode: str | None = None, listen: list[str] | None = None, connect: list[str] | None = None
) -> zenoh.Config:
    """The zenoh.Config of `cfg`: its file, then its fields (mode/listen/connect overridable), overrides."""
    mode = mode or cfg.mode
    if mode not in MODES:
        raise ValueError(f"zenoh mode must be one of {MODES}, got {mode!r}")
    conf = zenoh.Config.from_file(cfg.zenoh_config_file) if cfg.zenoh_config_file else zenoh.Config()
    settings: dict[str, Any] = {
        "mode": mode,
        "listen/endpoints": list(cfg.listen if listen is None else listen),
        "connect/endpoints": list(cfg.connect if connect is None else connect),
        # -1: wait for ever; a client otherwise gives up at once when no router is up yet
        "connect/timeout_ms": -1 if cfg.connect_timeout_s < 0 else int(cfg.connect_timeout_s * 1000),
        "scouting/multicast/enabled": bool(cfg.multicast_scouting),
        "transport/link/rx/max_message_size": int(cfg.max_message_size),
        "transport/shared_memory/enabled": bool(cfg.shared_memory),
    }
    for path, value in settings.items():
        conf.insert_json5(path, json.dumps(value))
    for path, value in cfg.zenoh_overrides.items():
        conf.insert_json5(path, value)
    return conf


def _callback(fn: Callable[[Any], None]) -> zenoh.handlers.Callback:
    # run on Zenoh's thread: no Python thread for the interpreter to wait on at exit
    return zenoh.handlers.Callback(fn, indirect=False)


class ZenohPublisher:
    """A declared Zenoh publisher that refuses payloads the receivers would silently drop."""

    def __init__(self, publisher: zenoh.Publisher, key: str, max_message_size: int) -> None:
        self.key = key
        self._publisher = publisher
        self._max = max_message_size

    def put(self, payload: bytes) -> None:
        if len(payload) > self._max:
            raise WireError("size", f"{len(payload)} bytes > max_message_size {self._max}")
        self._publisher.put(payload)

    def close(self) -> None:
        self._publisher.undeclare()


class ZenohLatestServer(LatestValue):
    """A queryable answering with the latest payload; replies come from a server thread.

    `queries.dropped` counts queries refused because QUERY_BACKLOG were already waiting.
    """

    def __init__(self, session: zenoh.Session, key: str) -> None:
        super().__init__(key)
        self.queries: BoundedInbox[zenoh.Query] = BoundedInbox(QUERY_BACKLOG)
        # a query dropped on overflow is finalised when its last reference goes: the asker sees no reply
        self._queryable = session.declare_queryable(key, _callback(self.queries.offer))
        self._thread = threading.Thread(target=self._serve, name=f"serve {key}", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while (query := self.queries.get()) is not None:
            with query:
                payload = self.latest()
                if payload is None:
                    self.unanswered += 1
                    continue
                try:
                    query.reply(self.key, payload)
                    self.answered += 1
                except zenoh.ZError as exc:
                    # the asker gave up or the session is closing: nothing to answer
                    self.unanswered += 1
                    log.debug("reply on %s failed: %s", self.key, exc)

    def close(self) -> None:
        self._queryable.undeclare()
        self.queries.close()
        self._thread.join(timeout=5.0)


def zenoh_priority(key: str, enabled: bool = True) -> zenoh.Priority:
    """The wiring table's priority for the route of `key` (Zenoh's default for keys outside it)."""
    r = route_of_key(key) if enabled else None
    if r is None or r.priority == "-":
        return zenoh.Priority.DEFAULT
    return getattr(zenoh.Priority, r.priority.upper())


class ZenohTransport:
    """`Transport` over one Zenoh session built from a TransportConfig."""

    def __init__(self, cfg: TransportConfig, stop: Any = None) -> None:
        """`stop` (an Event): with connect_timeout_s < 0, stop waiting for a router once it is set."""
        self.cfg = cfg
        forever = cfg.connect_timeout_s < 0
        # waiting for ever happens in 1 s attempts: zenoh.open itself cannot be interrupted by a signal
        attempt = dataclasses.replace(cfg, connect_timeout_s=1.0) if forever else cfg
        waiting = False
        while True:
            try:
                self.session = zenoh.open(zenoh_config(attempt))
                break
            except zenoh.ZError as exc:
                if not forever or (stop is not None and stop.is_set()):
                    # callers retry on ConnectionError without importing zenoh
                    raise ConnectionError(
                        f"cannot open a zenoh session ({cfg.mode}, connect={cfg.connect}): {exc}"
                    ) from exc
                if not waiting:  # once: a user sees why the role is idle
                    log.info("no router at %s yet: waiting for one (connect_timeout_s < 0)", cfg.connect)
                    waiting = True
        self._owned: list = []
        self._closed = False

    def _own(self, obj):
        self._owned.append(obj)
        return obj

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("transport is closed")

    def publisher(self, key: str, *, congestion: str = "block") -> ZenohPublisher:
        self._check_open()
        cc = zenoh.CongestionControl.BLOCK if check_congestion(congestion) == "block" else zenoh.CongestionControl.DROP
        pub = self.session.declare_publisher(
            key, congestion_control=cc, priority=zenoh_priority(key, self.cfg.priorities)
        )
        return self._own(ZenohPublisher(pub, key, self.cfg.max_message_size))

    def subscribe(
        self, key_expr: str, *, capacity: int | None = None, overflow: str = "drop_new", wait_s: float = 0.0
    ) -> Subscription:
        self._check_open()
        sub = Subscription(key_expr, capacity or self.cfg.inbox_capacity, overflow, wait_s)

        def on_sample(sample: zenoh.Sample) -> None:
            # copy out of Zenoh's buffer and push; no network call, waits at most wait_s (< 5 s)
            sub.offer(Received(str(sample.key_expr), sample.payload.to_bytes()))

        zsub = self.session.declare_subscriber(key_expr, _callback(on_sample))
        sub._on_close = zsub.undeclare
        return self._own(sub)

    def serve_latest(self, key: str) -> ZenohLatestServer:
        self._check_open()
        return self._own(ZenohLatestServer(self.session, key))

    def fetch(self, key: str, *, timeout: float | None = None) -> bytes | None:
        self._check_open()
        timeout = self.cfg.query_timeout_s if timeout is None else timeout
        for reply in self.session.get(key, timeout=timeout):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
        return None

    def declare_alive(self, key: str) -> Token:
        self._check_open()
        token = self.session.liveliness().declare_token(key)
        return self._own(Token(key, token.undeclare))

    def alive_now(self, key_expr: str, timeout: float | None = None) -> set[str]:
        """Keys of the live tokens matching `key_expr`, asked of the network now."""
        timeout = self.cfg.query_timeout_s if timeout is None else timeout
        replies = self.session.liveliness().get(key_expr, timeout=timeout)
        return {str(r.ok.key_expr) for r in replies if r.ok is not None}

    def watch_alive(self, key_expr: str) -> AliveWatcher:
        self._check_open()
        watcher = AliveWatcher(key_expr, resync=lambda: self.alive_now(key_expr))

        def on_change(sample: zenoh.Sample) -> None:
            watcher.events.offer((str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

        zsub = self.session.liveliness().declare_subscriber(key_expr, _callback(on_change), history=True)
        watcher._on_close = zsub.undeclare
        return self._own(watcher)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        owned, self._owned = self._owned, []
        try:
            for obj in reversed(owned):
                try:
                    obj.close()
                except (zenoh.ZError, RuntimeError) as exc:
                    # keep closing the rest: one failed undeclare must not leak the session. RuntimeError
                    # ("Already borrowed"): a put still blocked on a sender thread holds the publisher
                    log.warning("closing %s failed: %s", type(obj).__name__, exc)
        finally:
            self.session.close()

    def __enter__(self) -> "ZenohTransport":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_router(cfg: TransportConfig) -> zenoh.Session:
    """A Zenoh session in router mode on `cfg.router_listen` (and `cfg.router_connect`)."""
    return zenoh.open(zenoh_config(cfg, mode="router", listen=cfg.router_listen, connect=cfg.router_connect))


def run_router(cfg: TransportConfig, stop: Any = None, ready: Any = None) -> None:
    """Run the run's router until `stop` (an Event) is set or SIGINT/SIGTERM: gvf-router's body.

    `ready` (an Event, e.g. a multiprocessing one) is set once the router listens.
    """
    # the handler only sets a thread Event: setting a multiprocessing Event from a handler
    # that interrupted that same Event's wait can deadlock
    signalled = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: signalled.set())
    try:
        with open_router(cfg) as session:
            log.info("zenoh router %s listening on %s", session.zid(), cfg.router_listen)
            if ready is not None:
                ready.set()
            while not signalled.wait(0.2) and not (stop is not None and stop.is_set()):
                pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def router_role(ctx) -> None:
    """The router role (`common.roles`): the run's router until ctx.stop."""
    run_router(ctx.cfg.transport, ctx.stop)
