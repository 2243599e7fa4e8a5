"""Actor chunks -> wire -> learner transitions: consecutive, frames once, cumulants aligned."""

import numpy as np
import torch

from actors.chunker import ChunkBuilder
from actors.controllers.kinematic import KinematicController
from actors.envs.lane_drive import LaneDriveVectorEnv
from common import wire
from learner.ingest import SequenceTracker, chunks_to_transitions
from learner.replay import compact


def _collect(steps=40, chunk_len=8):
    env = LaneDriveVectorEnv(2, track="alder", random_start=False, direction="ccw")
    obs, info = env.reset(seed=0)
    builder = ChunkBuilder("a", 2, chunk_len)
    for i in range(2):
        builder.start(i, {k: v[i] for k, v in obs.items()}, float(info["alpha"][i]), float(info["beta"][i]), 0)
    chunks, history = [], []
    driver = KinematicController()
    for t in range(steps):
        action = driver.act(info)
        action[1] = (1.0, 1.0)  # env 0 keeps the lane, env 1 leaves the road
        nobs, reward, term, trunc, info = env.step(action)
        for i in range(2):
            done = term[i] or trunc[i]
            src, inf = (info["final_obs"][i], info["final_info"]) if done else ({k: v[i] for k, v in nobs.items()}, info)
            if i == 0:
                history.append((src["image"].copy(), float(inf["alpha"][i])))
            c = builder.add(i, action[i], float(reward[i]), bool(term[i]), bool(trunc[i]), float(inf["alpha"][i]), float(inf["beta"][i]), src, t)
            if c is not None:
                chunks.append(wire.decode(wire.encode(c)))
            if done:
                builder.start(i, {k: v[i] for k, v in nobs.items()}, float(info["alpha"][i]), float(info["beta"][i]), t)
        obs = nobs
    return chunks, history


def test_chunks_become_consecutive_transitions_with_next_state_cumulants():
    chunks, history = _collect()
    env0 = [c for c in chunks if c.env == 0]
    assert [c.step0 for c in env0] == [0, 8, 16, 24, 32]
    td = chunks_to_transitions(env0)
    assert td.shape[0] == 40
    # next observation of step t is the observation of step t+1, and equals what the env returned
    assert torch.equal(td["next", "image"][:-1], td["image"][1:])
    np.testing.assert_array_equal(td["next", "image"][5].numpy(), history[5][0])
    np.testing.assert_allclose(td["next", "alpha"][:, 0].numpy(), [a for _, a in history], rtol=1e-6)
    np.testing.assert_allclose(td["alpha"][1:, 0].numpy(), td["next", "alpha"][:-1, 0].numpy())


def test_episode_end_closes_a_chunk_and_sequence_numbers_are_per_actor():
    chunks, _ = _collect()
    env1 = [c for c in chunks if c.env == 1]
    end = next(k for k, c in enumerate(env1) if c.terminated.any())
    assert env1[end].terminated[-1] and not env1[end].terminated[:-1].any()
    assert (env1[end + 1].episode, env1[end + 1].step0) == (env1[end].episode + 1, 0)
    assert sorted(c.seq for c in chunks) == list(range(len(chunks)))


def test_frames_cross_the_wire_once():
    chunks, _ = _collect()
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
    chunks, _ = _collect()
    full, lean = chunks_to_transitions(chunks), chunks_to_transitions(chunks, next_image=False)
    assert "image" not in lean["next"].keys() and torch.equal(lean["next", "frame"], full["next", "image"][:, :1])
    rho = torch.rand(full.shape[0], 1)
    a, b = compact(full, rho), compact(lean, rho)
    assert all(torch.equal(a[k], b[k]) for k in a.keys())
