"""The real actor loop (actors.actor.run_actor) on a fake env over the in-process transport:
what it sends (consecutive chunks, episode ends, summaries, versions) and what it obeys
(weights fetched at start, control stop, the learner's flow pause)."""

import threading
import time

import numpy as np

from common import wire
from common.transport.inproc import Bus
from tests.actor_harness import FakeLearner
from tests.actor_harness import start_actor as _start
from tests.helpers import TINY, compose_run


def test_the_actor_loop_sends_consecutive_chunks_ends_episodes_and_stops_at_its_step_limit():
    cfg = compose_run([*TINY, "transport=inproc", "actor.num_envs=2", "actor.chunk_len=8", "actor.max_env_steps=80"])
    bus, made = Bus(), {}
    learner = FakeLearner(cfg, bus)
    thread, stats = _start(cfg, bus, threading.Event(), made)
    thread.join(60)
    assert not thread.is_alive() and stats["env_steps"] == 80 and made["env"].closed
    chunks = learner.chunks()
    assert sorted(c.seq for c in chunks) == list(range(len(chunks))) and stats["chunks"] == len(chunks)
    assert {c.policy_version for c in chunks} == {3} and stats["weights_loaded"] == 1  # fetched at start
    car0 = [c for c in chunks if c.env == 0]
    assert [c.step0 for c in car0] == [0, 8, 16, 24, 32]  # 40 steps, chunks of 8
    for c in chunks:  # every frame once, in order: frame j+1 shows step step0 + j
        np.testing.assert_array_equal(c.frames[1:, 0, 0], (c.step0 + np.arange(c.num_steps + 1)) % 256)
        np.testing.assert_allclose(c.alpha, (c.step0 + np.arange(c.num_steps + 1)) / 100, rtol=1e-6)
    car1 = [c for c in chunks if c.env == 1]
    assert [(c.episode, c.step0, c.num_steps) for c in car1[:3]] == [(0, 0, 8), (0, 8, 5), (1, 0, 8)]
    assert car1[1].terminated[-1] and not car1[1].terminated[:-1].any() and not car1[0].terminated.any()
    episodes = learner.episodes()
    assert [(e.env, e.episode, e.steps, e.track) for e in episodes] == [
        (1, 0, 13, "alder"),
        (1, 1, 13, "alder"),
        (1, 2, 13, "alder"),
    ]
    assert made["sampler"].steps[made["sampler"].names.index("alder")] > 0  # the sampler heard of each end


def test_the_actor_obeys_the_learners_flow_pause_and_a_control_stop():
    cfg = compose_run([*TINY, "transport=inproc", "actor.num_envs=2", "actor.chunk_len=8"])
    bus, made, stop = Bus(), {}, threading.Event()
    learner = FakeLearner(cfg, bus)
    control = learner.t.publisher(learner.keys.control)
    flow = learner.t.publisher(learner.keys.flow)
    thread, stats = _start(cfg, bus, stop, made)
    deadline = time.monotonic() + 30
    while not learner.chunks_in and time.monotonic() < deadline:
        time.sleep(0.01)
    flow.put(wire.encode(wire.Control("pause")))
    time.sleep(0.3)  # a chunk in flight may still land
    learner.chunks()
    time.sleep(0.5)
    assert learner.chunks() == [] and thread.is_alive()  # paused: no steps, still alive
    flow.put(wire.encode(wire.Control("resume")))
    deadline = time.monotonic() + 30
    while not learner.chunks_in and time.monotonic() < deadline:
        time.sleep(0.01)
    assert learner.chunks()  # stepping again
    control.put(wire.encode(wire.Control("stop")))
    thread.join(30)
    assert not thread.is_alive() and stop.is_set()  # the control stop ended the loop
    assert stats["paused_s"] > 0.3


def test_weights_that_do_not_fit_and_unknown_roads_are_counted_and_the_actor_drives_on():
    cfg = compose_run([*TINY, "transport=inproc", "actor.num_envs=2", "actor.chunk_len=8", "actor.max_env_steps=4000"])
    bus, made = Bus(), {}
    learner = FakeLearner(cfg, bus)
    thread, stats = _start(cfg, bus, threading.Event(), made)
    deadline = time.monotonic() + 30
    while not learner.chunks_in and time.monotonic() < deadline:
        time.sleep(0.01)
    good = wire.decode(learner.t.fetch(learner.keys.weights))
    name = next(iter(good.tensors))
    missing = wire.Weights(99, {k: v for k, v in good.tensors.items() if k != name}, epoch=1)
    learner.t.publisher(learner.keys.weights).put(wire.encode(missing))  # once, it killed an actor
    learner.t.publisher(learner.keys.tracks).put(wire.encode(wire.TrackTable(1, {"no-such-road": 5})))
    thread.join(60)
    assert not thread.is_alive() and stats["env_steps"] == 4000
    assert stats["rejected"] == 2 and stats["policy_version"] == 3  # the learner's policy kept
