"""Chunks of the real actor loop (on a fake env) -> wire -> learner transitions: consecutive,
frames once, cumulants aligned."""

import numpy as np
import torch

from common import wire
from common.transport.inproc import Bus
from common.wire_rules import SequenceTracker
from learner.ingest import chunks_to_transitions
from learner.replay import compact
from tests.actor_harness import actor_chunks
from tests.helpers import TINY, compose_run


def _collect():
    """Chunks of the real actor loop: car 0 drives 40 steps in chunks of 8, car 1 ends every 13."""
    cfg = compose_run([*TINY, "transport=inproc", "actor.num_envs=2", "actor.chunk_len=8", "actor.max_env_steps=80"])
    chunks, _, _ = actor_chunks(cfg, Bus())
    return chunks


def test_chunks_become_consecutive_transitions_with_next_state_cumulants():
    env0 = [c for c in _collect() if c.env == 0]
    td = chunks_to_transitions(env0)
    assert td.shape[0] == 40
    # next observation of step t is the observation of step t+1 (fake frames show their step)
    assert torch.equal(td["next", "image"][:-1], td["image"][1:])
    np.testing.assert_array_equal(td["image"][:, 0, 0, 0].numpy(), np.arange(40))
    np.testing.assert_array_equal(td["next", "image"][:, 0, 0, 0].numpy(), np.arange(1, 41))
    np.testing.assert_allclose(
        td["next", "alpha"][:, 0].numpy(), np.arange(1, 41) / 100, rtol=1e-6
    )  # cumulants of s_t+1
    np.testing.assert_allclose(td["alpha"][1:, 0].numpy(), td["next", "alpha"][:-1, 0].numpy())
    np.testing.assert_array_equal(td["next", "last_action"].numpy(), td["action"].numpy())


def test_episode_end_closes_a_chunk_and_sequence_numbers_are_per_actor():
    chunks = _collect()
    env1 = [c for c in chunks if c.env == 1]
    end = next(k for k, c in enumerate(env1) if c.terminated.any())
    assert env1[end].terminated[-1] and not env1[end].terminated[:-1].any()
    assert (env1[end + 1].episode, env1[end + 1].step0) == (env1[end].episode + 1, 0)
    td = chunks_to_transitions(env1[: end + 1])
    assert td["next", "terminated"][:, 0].tolist() == [False] * 12 + [True]  # the 13th step ends it
    assert sorted(c.seq for c in chunks) == list(range(len(chunks)))


def test_frames_cross_the_wire_once():
    chunks = _collect()
    c = chunks[0]
    assert c.frames.shape[0] == c.num_steps + 2
    assert len(wire.encode(c)) < 1.1 * c.frames.nbytes


def test_sequence_tracker_counts_gaps_and_restarts():
    s = SequenceTracker()
    for seq in [0, 1, 2, 5, 6]:
        s.see("a", seq)
    s.see("b", 0)
    s.see("a", 0)  # actor a restarted
    s.see("a", 2)
    assert (s.lost, s.restarts, s.received) == (2 + 1, 1, 8)  # seqs 3, 4, then 1 after the restart


def test_next_frame_only_batches_store_the_same_replay_items():
    chunks = _collect()
    full, lean = chunks_to_transitions(chunks), chunks_to_transitions(chunks, next_image=False)
    assert "image" not in lean["next"].keys() and torch.equal(lean["next", "frame"], full["next", "image"][:, :1])
    rho = torch.rand(full.shape[0], 1)
    a, b = compact(full, rho), compact(lean, rho)
    assert all(torch.equal(a[k], b[k]) for k in a.keys())
