"""Transport: keys and the in-process transport (real Zenoh: test_transport_zenoh.py; the inbox:
test_inbox.py). No test asserts a timing."""

from __future__ import annotations

import numpy as np
import pytest

from common.config.transport import TransportConfig
from common.keys import Keys, key_matches
from common.transport import Transport, make_transport
from common.transport.inproc import Bus, InprocTransport
from common.wire import Weights, WireError, decode, encode
from tests.transport_helpers import small_chunk

# --- keys ------------------------------------------------------------------------


def test_keys_and_matching():
    keys = Keys("r1")
    assert keys.transitions("a7") == "gvf/r1/transitions/a7"
    assert key_matches(keys.all_transitions, keys.transitions("a7"))
    assert not key_matches(keys.all_transitions, keys.episodes("a7"))
    assert key_matches(keys.all_alive(), keys.alive("actor", "a1"))
    assert key_matches(keys.all_alive("actor"), keys.alive("actor", "a1"))
    assert not key_matches(keys.all_alive("learner"), keys.alive("actor", "a1"))
    assert key_matches("a/**", "a") and not key_matches("a/*", "a")
    for bad in ("a/b", "*", "", "a b", "$x", ".."):
        with pytest.raises(ValueError):
            keys.transitions(bad)
    assert keys.publish("transitions", "actor", actor="a7") == keys.transitions(
        "a7"
    )  # the table and the builders agree
    assert keys.subscribe("transitions", "learner") == keys.all_transitions


def test_route_of_key_finds_each_route_and_nothing_else():
    from common.keys import route_of_key

    keys = Keys("r1")
    found = {
        k: route_of_key(k).name for k in (keys.transitions("a7"), keys.weights, keys.flow, keys.alive("actor", "a1"))
    }
    assert list(found.values()) == ["transitions", "weights", "flow", "alive"]
    for outside in ("gvf/r1/weights/extra", "gvf/r1/nothing", "other/r1/weights", "gvf", "gvf/r1"):
        assert route_of_key(outside) is None, outside


# --- in-process transport ------------------------------------------------------------------


def test_inproc_pub_sub_fetch_and_liveliness():
    bus = Bus()
    keys = Keys("t")
    cfg = TransportConfig(backend="inproc")
    with make_transport(cfg, bus) as learner, make_transport(cfg, bus) as actor:
        assert isinstance(learner, Transport)
        chunks = learner.subscribe(keys.all_transitions, capacity=8)
        other = learner.subscribe(keys.all_episodes)
        pub = actor.publisher(keys.transitions("a0"))
        for seq in range(3):
            pub.put(encode(small_chunk(seq)))
        got = chunks.drain()
        assert [decode(r.payload).seq for r in got] == [0, 1, 2] and len(other) == 0
        assert {r.key for r in got} == {keys.transitions("a0")}

        server = learner.serve_latest(keys.weights)
        assert actor.fetch(keys.weights) is None
        server.update(encode(Weights(5, {"w": np.ones(2, np.float32)})))
        assert decode(actor.fetch(keys.weights)).version == 5 and server.answered == 1

        watcher = learner.watch_alive(keys.all_alive("actor"))
        token = actor.declare_alive(keys.alive("actor", "a0"))
        assert watcher.alive() == {keys.alive("actor", "a0")}
        token.close()
        assert watcher.alive() == frozenset()
        actor.declare_alive(keys.alive("actor", "a1"))
    # closing the actor's transport withdrew its token and its subscriptions
    assert bus.alive_keys(keys.all_alive()) == set() and chunks.closed


def test_inproc_full_inbox_counts_drops_and_size_limit():
    cfg = TransportConfig(backend="inproc", max_message_size=1000)
    with InprocTransport(cfg) as t:
        sub = t.subscribe("k/*", capacity=3)
        latest = t.subscribe("k/*", capacity=1, overflow="drop_old")
        pub = t.publisher("k/x")
        for i in range(10):
            pub.put(bytes([i]))
        assert len(sub) == 3 and sub.dropped == 7 and sub.received == 10
        assert latest.drain()[0].payload == bytes([9])
        with pytest.raises(WireError) as info:
            pub.put(b"x" * 1001)
        assert info.value.kind == "size"
    with pytest.raises(RuntimeError):
        t.subscribe("k/*")


def test_make_transport_rejects_unknown_backend():
    with pytest.raises(ValueError):
        make_transport(TransportConfig(backend="carrier-pigeon"))
