"""The bounded inbox every receiver drains: drops and counts when full, or first waits up to
`wait_s` for room, which over Zenoh is back-pressure on a BLOCK publisher instead of a loss."""

from __future__ import annotations

import threading
import time

import pytest

from common.keys import Keys
from common.transport.inbox import BoundedInbox
from tests.transport_helpers import client_cfg, router_port, wait_for  # noqa: F401 (router_port: fixture)


def test_inbox_drops_and_counts_when_full():
    new = BoundedInbox(2)
    assert [new.offer(i) for i in range(5)] == [True, True, False, False, False]
    assert new.drain() == [0, 1] and (new.received, new.dropped) == (5, 3)
    old = BoundedInbox(2, overflow="drop_old")
    for i in range(5):
        old.offer(i)
    assert old.drain() == [3, 4] and old.dropped == 3


def test_inbox_get_waits_and_close_wakes():
    inbox = BoundedInbox(4)
    assert inbox.get(timeout=0.01) is None
    threading.Timer(0.05, inbox.offer, args=("x",)).start()
    assert inbox.get(timeout=10) == "x"
    threading.Timer(0.05, inbox.close).start()
    assert inbox.get() is None and not inbox.offer("late") and inbox.dropped == 1


def test_a_full_inbox_with_wait_keeps_the_item_once_the_owner_takes_one():
    inbox = BoundedInbox(1, wait_s=4.0)
    inbox.offer("a")
    threading.Timer(0.05, inbox.drain).start()
    assert inbox.offer("b")  # waited for the drain instead of dropping
    assert inbox.drain() == ["b"] and (inbox.waited, inbox.dropped) == (1, 0)


def test_a_full_inbox_drops_after_its_wait_and_close_wakes_a_waiting_producer():
    inbox = BoundedInbox(1, wait_s=0.05)
    inbox.offer("a")
    assert not inbox.offer("late") and (inbox.waited, inbox.dropped) == (1, 1)
    slow = BoundedInbox(1, wait_s=4.0)
    slow.offer("a")
    threading.Timer(0.05, slow.close).start()
    assert not slow.offer("b") and slow.dropped == 1 and slow.drain() == ["a"]


def test_wait_must_stay_below_zenohs_close_of_a_blocked_link():
    with pytest.raises(ValueError, match="wait_s"):
        BoundedInbox(4, wait_s=5.0)


def test_over_zenoh_a_waiting_inbox_slows_a_block_publisher_and_loses_nothing(router_port):  # noqa: F811
    """The counterpart of test_zenoh_full_inbox_counts_drops (wait 0: 46 of 50 dropped): with a
    wait, a slow owner of a 4-item inbox still receives every one of 300 puts, in order."""
    from common.transport.zenoh_backend import ZenohTransport

    keys = Keys("backpressure")
    cfg = client_cfg(router_port)
    with ZenohTransport(cfg) as learner, ZenohTransport(cfg) as actor:
        sub = learner.subscribe(keys.all_episodes, capacity=4, wait_s=2.0)
        probe = learner.subscribe(keys.control)
        pub, probe_pub = actor.publisher(keys.episodes("a0")), actor.publisher(keys.control)
        assert wait_for(lambda: (probe_pub.put(b"probe"), len(probe) > 0)[1])
        got: list[bytes] = []
        done = threading.Event()

        def slow_owner() -> None:
            while len(got) < 300 and not done.is_set():
                got.extend(r.payload for r in sub.drain(2))
                time.sleep(0.002)

        owner = threading.Thread(target=slow_owner, daemon=True)
        owner.start()
        try:
            for i in range(300):
                pub.put(i.to_bytes(2, "little"))
            assert wait_for(lambda: len(got) >= 300, timeout=60)
        finally:
            done.set()
            owner.join(10)
        assert got == [i.to_bytes(2, "little") for i in range(300)]
        assert sub.dropped == 0 and sub.waited > 0
