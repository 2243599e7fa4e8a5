"""The learner's intake (learner.ingestor) on hand-made payloads: what it inserts, what it counts."""

import numpy as np
import torch

from common import wire
from common.transport import Received, Subscription
from learner.ingestor import Ingestor


def chunk(actor="a", env=0, episode=0, seq=0, step0=0, steps=4, version=0, end=False):
    return wire.TransitionChunk(
        actor=actor,
        env=env,
        episode=episode,
        seq=seq,
        policy_version=version,
        step0=step0,
        frames=np.zeros((steps + 2, 64, 128), np.uint8),
        speed=np.full((steps + 1, 1), 0.5, np.float32),
        last_action=np.zeros((steps + 1, 2), np.float32),
        action=np.zeros((steps, 2), np.float32),
        reward=np.ones(steps, np.float32),
        terminated=np.array([False] * (steps - 1) + [end]),
        truncated=np.zeros(steps, bool),
        alpha=np.zeros(steps + 1, np.float32),
        beta=np.zeros(steps + 1, np.float32),
    )


def inbox(*payloads, key="gvf/r/transitions/a"):
    sub = Subscription(key, capacity=100)
    for p in payloads:
        sub.offer(Received(key, p))
    return sub


def test_good_chunks_become_one_batch_and_bad_ones_are_counted_by_kind():
    intake = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64)
    chunks = inbox(wire.encode(chunk(seq=0)), b"\x00garbage", wire.encode(chunk(seq=1, step0=4, steps=3)))
    batch = intake.take(chunks, inbox(), updates=10)
    assert batch.shape[0] == 7 and "frame" in batch["next"].keys()  # the next state's new frame only
    assert intake.counters == {"inserted": 7, "episodes": 0, "chunks": 2}
    assert intake.rejects.total == 1 and sum(intake.rejects.counts.values()) == 1
    assert list(intake.lags) == [10, 10] and intake.mean_chunk_steps() == 3.5
    assert intake.take(inbox(), inbox(), updates=10) is None


def test_sequence_gaps_count_lost_chunks_and_a_drain_takes_at_most_ingest_batch():
    intake = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=2)
    chunks = inbox(*(wire.encode(chunk(seq=s)) for s in (0, 1, 4)))
    assert intake.take(chunks, inbox(), updates=0).shape[0] == 8 and len(chunks) == 1
    intake.take(chunks, inbox(), updates=0)
    assert intake.seq.lost == 2 and intake.progress()["lost_chunks"] == 2


def test_the_first_whole_episode_of_one_env_is_held_out_and_summaries_feed_the_track_table():
    intake = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64)
    first = [chunk(seq=0), chunk(env=1, seq=1), chunk(seq=2, step0=4, end=True)]
    intake.take(inbox(*map(wire.encode, first)), inbox(), updates=0)
    assert intake.held_out is not None and intake.held_out.shape[0] == 8  # env 0's two chunks, in order
    assert bool(intake.held_out["next", "terminated"][-1]) and "image" in intake.held_out["next"].keys()
    summary = wire.EpisodeSummary("a", 0, 0, "alder-r", 8, 8.0, 0)
    intake.take(inbox(), inbox(wire.encode(summary), key="gvf/r/episodes/a"), updates=0)
    assert intake.tracks == {"alder": 8} and intake.progress()["return_mean"] == 8.0


def test_the_steps_before_a_termination_are_kept_across_the_chunk_boundary_for_the_crash_memory():
    intake = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64, crash_steps=5)
    before, last = chunk(seq=0, steps=4), chunk(seq=2, step0=4, steps=3, end=True)
    before.reward[:], last.reward[:] = [0.1, 0.2, 0.3, 0.4], [0.5, 0.6, 0.7]  # step t's: (t + 1) / 10
    other = chunk(env=1, seq=1, steps=4)  # another env's chunk in between: never part of env 0's crash
    other.reward[:] = -1
    intake.take(inbox(*map(wire.encode, (before, other, last))), inbox(), updates=0)
    crash = intake.take_crashes()
    reward = crash["next", "reward"].reshape(-1)
    assert torch.allclose(reward, torch.tensor([0.3, 0.4, 0.5, 0.6, 0.7]))  # the last 5 steps, in order
    assert crash["next", "terminated"].reshape(-1).tolist() == [False] * 4 + [True]
    assert "frame" in crash["next"].keys() and intake.take_crashes() is None  # handed over once


def test_only_terminations_feed_the_crash_memory_and_a_new_episode_never_borrows_the_last_ones_steps():
    intake = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64, crash_steps=10)
    truncated = chunk(seq=0, steps=4)
    truncated.truncated[-1] = True
    next_episode = chunk(episode=1, seq=1, steps=2, end=True)  # its previous chunk is another episode's
    intake.take(inbox(*map(wire.encode, (truncated, next_episode))), inbox(), updates=0)
    assert intake.take_crashes().shape[0] == 2  # the new episode's own 2 steps only
    off = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64)  # crash_steps 0: nothing kept
    off.take(inbox(wire.encode(chunk(seq=0, end=True))), inbox(), updates=0)
    assert off.take_crashes() is None and not off._previous
