"""Transport over real Zenoh on 127.0.0.1: config, pub/sub through a router, full inboxes,
queryables, liveliness, peer mode, and each route's priority.

The router runs in a 'spawn' child process (forking after zenoh init hangs) and the clients in
this process; every session is closed and every process joined in `finally`. Waits poll with
generous deadlines so that a failure never hangs; no test asserts a timing.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from common.config.transport import TransportConfig
from common.keys import Keys
from common.transport import Transport
from common.wire import Control, TransitionChunk, Weights, WireError, decode, encode
from tests.helpers import free_port
from tests.transport_helpers import CTX, client_cfg, router_port, small_chunk, wait_for  # noqa: F401 (router_port: fixture)

REPO = Path(__file__).resolve().parents[1]


def _hold_token(cfg: TransportConfig, key: str, ready) -> None:
    from common.transport.zenoh_backend import ZenohTransport

    with ZenohTransport(cfg) as t:
        t.declare_alive(key)
        ready.set()
        time.sleep(60)


def test_zenoh_config_from_transport_config():
    from common.transport.zenoh_backend import zenoh_config

    cfg = TransportConfig(
        mode="peer",
        listen=["tcp/127.0.0.1:0"],
        max_message_size=12345,
        zenoh_overrides={"transport/link/tx/lease": "3000"},
    )
    conf = zenoh_config(cfg)

    def get(path):
        return json.loads(conf.get_json(path))

    assert get("mode") == "peer"
    assert get("listen/endpoints") == ["tcp/127.0.0.1:0"]
    assert get("scouting/multicast/enabled") is False
    assert get("transport/link/rx/max_message_size") == 12345
    assert get("transport/shared_memory/enabled") is False
    assert get("transport/link/tx/lease") == 3000
    with pytest.raises(ValueError):
        zenoh_config(TransportConfig(mode="satellite"))


def test_zenoh_config_file_then_fields(tmp_path):
    from common.transport.zenoh_backend import zenoh_config

    path = tmp_path / "zenoh.json5"
    path.write_text('{mode: "router", transport: {link: {tx: {lease: 4000}}}}')
    conf = zenoh_config(TransportConfig(zenoh_config_file=str(path)))
    assert json.loads(conf.get_json("transport/link/tx/lease")) == 4000
    assert json.loads(conf.get_json("mode")) == "client"  # the fields win over the file


def test_run_router_stops_on_its_event():
    from common.transport.zenoh_backend import ZenohTransport, run_router

    port = free_port()
    stop, ready = threading.Event(), threading.Event()
    cfg = TransportConfig(router_listen=[f"tcp/127.0.0.1:{port}"])
    thread = threading.Thread(target=run_router, args=(cfg, stop, ready), daemon=True)
    thread.start()
    try:
        assert ready.wait(30)
        with ZenohTransport(client_cfg(port)) as a, ZenohTransport(client_cfg(port)) as b:
            sub = a.subscribe("gvf/r/control")
            pub = b.publisher("gvf/r/control")
            assert wait_for(lambda: (pub.put(encode(Control("resume"))), len(sub) > 0)[1])
    finally:
        stop.set()
        thread.join(30)
    assert not thread.is_alive()


def test_zenoh_pub_sub_through_router(router_port):
    from common.transport.zenoh_backend import ZenohTransport

    keys = Keys("pubsub")
    cfg = client_cfg(router_port)
    with ZenohTransport(cfg) as learner, ZenohTransport(cfg) as actor:
        assert isinstance(learner, Transport)
        chunks = learner.subscribe(keys.all_transitions, capacity=64)
        pub = actor.publisher(keys.transitions("a0"))
        control = learner.subscribe(keys.control)
        launcher_pub = actor.publisher(keys.control)
        # a subscription reaches the publisher through the router: wait until a probe arrives
        assert wait_for(lambda: (launcher_pub.put(encode(Control("pause"))), len(control) > 0)[1])
        for seq in range(20):
            pub.put(encode(small_chunk(seq)))
        assert wait_for(lambda: len(chunks) >= 20)
        got = [decode(r.payload, expect=TransitionChunk) for r in chunks.drain()]
        assert [c.seq for c in got] == list(range(20)) and chunks.dropped == 0
        assert int(got[7].frames[0, 0, 0]) == 7
        with pytest.raises(WireError) as info:
            pub.put(b"x" * (cfg.max_message_size + 1))
        assert info.value.kind == "size"


def test_zenoh_full_inbox_counts_drops(router_port):
    from common.transport.zenoh_backend import ZenohTransport

    keys = Keys("drops")
    cfg = client_cfg(router_port)
    with ZenohTransport(cfg) as learner, ZenohTransport(cfg) as actor:
        sub = learner.subscribe(keys.all_episodes, capacity=4)
        probe = learner.subscribe(keys.control)
        pub, probe_pub = actor.publisher(keys.episodes("a0")), actor.publisher(keys.control)
        # declared after `sub` on the same link: once a probe arrives, the router knows `sub` too
        assert wait_for(lambda: (probe_pub.put(b"probe"), len(probe) > 0)[1])
        for i in range(50):
            pub.put(bytes([i]))
        assert wait_for(lambda: sub.received >= 50)
        assert sub.received == 50 and len(sub) == 4 and sub.dropped == 46
        assert [r.payload for r in sub.drain()] == [bytes([i]) for i in range(4)]


def test_a_publisher_busy_in_another_thread_does_not_stop_close(router_port, monkeypatch):
    """An actor stopped while its sender thread was still in a blocking put exited 1: undeclare
    raised RuntimeError ('Already borrowed') out of close. The rest must still close."""
    from common.transport.zenoh_backend import ZenohPublisher, ZenohTransport

    t = ZenohTransport(client_cfg(router_port))
    after = t.publisher(Keys("busy").episodes("a0"))
    busy = t.publisher(Keys("busy").control)  # closed first: owned objects close in reverse
    undeclare, closed = ZenohPublisher.close, []

    def close(self):
        if self is busy:
            raise RuntimeError("Already borrowed")
        closed.append(self.key)
        undeclare(self)

    monkeypatch.setattr(ZenohPublisher, "close", close)
    t.close()  # raises nothing
    assert closed == [after.key] and t.session.is_closed()


def test_zenoh_queryable_answers_latest_weights(router_port):
    from common.transport.zenoh_backend import ZenohTransport

    keys = Keys("query")
    cfg = client_cfg(router_port)
    with ZenohTransport(cfg) as learner, ZenohTransport(cfg) as actor:
        assert actor.fetch(keys.weights, timeout=1.0) is None  # nobody serves yet
        server = learner.serve_latest(keys.weights)
        payload = encode(Weights(3, {"pi.w": np.arange(6, dtype=np.float32).reshape(2, 3)}))
        server.update(payload)
        assert wait_for(lambda: actor.fetch(keys.weights, timeout=1.0) == payload)
        assert decode(actor.fetch(keys.weights)).version == 3 and server.answered >= 2


def test_zenoh_liveliness_sees_a_killed_process_go(router_port):
    from common.transport.zenoh_backend import ZenohTransport

    keys = Keys("alive")
    cfg = client_cfg(router_port)
    key = keys.alive("actor", "a9")
    ready = CTX.Event()
    proc = CTX.Process(target=_hold_token, args=(cfg, key, ready), daemon=True)
    try:
        with ZenohTransport(cfg) as learner:
            own = learner.declare_alive(keys.alive("learner", "main"))
            watcher = learner.watch_alive(keys.all_alive("actor"))
            proc.start()
            assert ready.wait(30)
            assert wait_for(lambda: key in watcher.alive())
            assert learner.alive_now(keys.all_alive()) == {key, own.key}
            proc.kill()
            assert wait_for(lambda: key not in watcher.alive())
            assert watcher.alive() == frozenset()
    finally:
        if proc.is_alive():
            proc.kill()
        if proc.pid is not None:
            proc.join()


def test_zenoh_peer_mode_without_router():
    from common.transport.zenoh_backend import ZenohTransport

    port = free_port()
    listener = TransportConfig(mode="peer", listen=[f"tcp/127.0.0.1:{port}"], connect=[])
    dialer = TransportConfig(mode="peer", connect=[f"tcp/127.0.0.1:{port}"], connect_timeout_s=5.0)
    with ZenohTransport(listener) as a, ZenohTransport(dialer) as b:
        sub = a.subscribe("gvf/peers/control")
        pub = b.publisher("gvf/peers/control")
        assert wait_for(lambda: (pub.put(encode(Control("stop"))), len(sub) > 0)[1])
        assert decode(sub.get(timeout=1).payload) == Control("stop")


def test_zenoh_client_without_router_raises_connection_error():
    from common.transport.zenoh_backend import ZenohTransport

    with pytest.raises(ConnectionError):
        ZenohTransport(TransportConfig(mode="client", connect=[f"tcp/127.0.0.1:{free_port()}"], connect_timeout_s=0))


def test_unclosed_session_does_not_hang_the_interpreter():
    script = textwrap.dedent("""
        from common.config.transport import TransportConfig
        from common.transport.zenoh_backend import ZenohTransport
        t = ZenohTransport(TransportConfig(mode="peer", listen=[], connect=[]))
        t.subscribe("gvf/x/transitions/*"); t.serve_latest("gvf/x/weights")
        t.watch_alive("gvf/x/alive/**"); t.declare_alive("gvf/x/alive/actor/a")
        print("leaving without close", flush=True)
    """)
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "leaving without close" in done.stdout


@pytest.mark.parametrize("priorities", [True, False])
def test_zenoh_routes_arrive_at_their_wiring_priority(router_port, priorities):
    import zenoh

    from common.keys import route_of_key
    from common.transport.zenoh_backend import ZenohTransport

    keys = Keys(f"prio-{priorities}")
    cfg = client_cfg(router_port)
    seen: dict[str, zenoh.Priority] = {}
    with ZenohTransport(cfg) as listener, ZenohTransport(client_cfg(router_port, priorities=priorities)) as sender:
        cb = zenoh.handlers.Callback(lambda s: seen.setdefault(str(s.key_expr), s.priority), indirect=False)
        listener.session.declare_subscriber(f"{keys.root}/**", cb)
        sent = [keys.transitions("a0"), keys.weights, keys.tracks, keys.flow, keys.control]
        pubs = [sender.publisher(k) for k in sent]
        assert wait_for(lambda: ([p.put(b"x") for p in pubs], len(seen) == len(sent))[1])
    want = {k: getattr(zenoh.Priority, route_of_key(k).priority.upper()) for k in sent}
    assert seen == (want if priorities else dict.fromkeys(sent, zenoh.Priority.DATA))
    # control overtakes weights, which overtake transitions (Zenoh serves a lower number first)
    assert int(want[keys.control]) < int(want[keys.weights]) < int(want[keys.transitions("a0")])
