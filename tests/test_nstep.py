"""n-step returns for DDPG's target (scale.n_step, learner.nstep): windows end at chunk ends, the
bootstrap state is the right stored step after the ring wraps, and torchrl's TD(0) raises gamma to m."""

import dataclasses

import pytest
import torch
from tensordict import TensorDict

from common.config.agent import AgentConfig, check_scale
from learner.core import LearningCore
from learner.ingest import chunks_to_transitions
from learner.nstep import nstep_columns, steps_left
from tests.core_fixtures import TINY, VARIANTS
from tests.test_chunks import _collect


def _chain(lengths, rewards, terminal_last=True):
    """Time-ordered chunks of `lengths` with the given rewards; each chunk ends its episode if asked."""
    n = sum(lengths)
    terminated = torch.zeros(n, 1, dtype=torch.bool)
    if terminal_last:
        terminated[torch.tensor(lengths).cumsum(0) - 1] = True
    return TensorDict(
        {
            "steps_left": steps_left(lengths),
            "next": {
                "reward": torch.tensor(rewards, dtype=torch.float32).reshape(-1, 1),
                "terminated": terminated,
                "truncated": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        batch_size=[n],
    )


def test_windows_stop_at_the_chunk_end_with_the_discounted_sum_and_the_last_steps_flags():
    cols = nstep_columns(_chain([4, 2], [1, 2, 3, 4, 5, 6]), n=3, gamma=0.5)
    assert cols["steps_to_next_obs"].reshape(-1).tolist() == [3, 3, 2, 1, 2, 1]
    expected = [1 + 1 + 0.75, 2 + 1.5 + 1, 3 + 2, 4, 5 + 3, 6]
    assert torch.allclose(cols["reward_n"].reshape(-1), torch.tensor(expected))
    # the windows that reach a chunk's last step carry its termination, the others do not
    assert cols["terminated_n"].reshape(-1).tolist() == [False, True, True, True, True, True]


def test_one_step_windows_are_the_transitions_themselves():
    chain = _chain([3, 3], [1, 2, 3, 4, 5, 6])
    cols = nstep_columns(chain, n=1, gamma=0.9)
    assert cols["steps_to_next_obs"].reshape(-1).tolist() == [1] * 6
    assert torch.equal(cols["reward_n"], chain["next", "reward"])
    assert torch.equal(cols["terminated_n"], chain["next", "terminated"])


def test_steps_left_that_do_not_count_down_are_refused():
    chain = _chain([3, 3], [0.0] * 6)
    chain["steps_left"] = torch.tensor([[3], [2], [2], [3], [2], [1]])
    with pytest.raises(ValueError, match="steps_left"):
        nstep_columns(chain, n=2, gamma=0.9)


def test_ingest_counts_each_chunks_steps_down_to_one():
    chunks = _collect()
    td = chunks_to_transitions(chunks)
    expected = torch.cat([torch.arange(c.num_steps, 0, -1) for c in chunks])
    assert torch.equal(td["steps_left"].reshape(-1), expected)


def test_config_refuses_a_step_count_below_one_and_the_crash_memory_with_it():
    with pytest.raises(ValueError, match="scale.n_step"):
        check_scale(dataclasses.replace(TINY, n_step=0))
    with pytest.raises(ValueError, match="scale.n_step"):
        check_scale(dataclasses.replace(TINY, n_step=3, crash_memory=100))


@pytest.mark.parametrize("agent", ["ddpg_image", "gvf_ddpg"])
def test_ddpg_sees_the_state_m_steps_on_with_m_steps_of_reward_after_the_ring_wraps(monkeypatch, agent):
    """Fake frames show their step in the episode (tests.fakes.CountingVectorEnv), reward 1 a step."""
    chunks = _collect()  # 2 cars, chunks of 8; car 1's episodes end every 13 steps
    scale = dataclasses.replace(TINY, n_step=3, buffer_size=50, warmup=20, batch_size=64)
    core = LearningCore(AgentConfig(name=agent, metrics_every=1, **VARIANTS[agent]), scale, seed=0)
    core.add(chunks_to_transitions(chunks, next_image=False))  # 80 steps into 50 slots: wraps
    seen = []
    sample = core.replay.sample_uniform
    monkeypatch.setattr(core.replay, "sample_uniform", lambda n: (seen.append(sample(n)), seen[-1])[1])
    uniform = core._uniform()
    m = uniform["steps_to_next_obs"].reshape(-1)
    assert set(m.tolist()) == {1, 2, 3}  # full windows and windows cut by chunk ends
    step, later = uniform["image"][:, 0, 0, 0].long(), uniform["next", "image"][:, 0, 0, 0].long()
    assert torch.equal(later - step, m)  # s_{t+m}, never across an episode's reset
    assert torch.equal(uniform["next", "image"][:, 1], core.replay.bootstrap(seen[-1])["image"].view(torch.uint8)[:, 0])
    assert torch.allclose(uniform["next", "reward"].reshape(-1), (1 - 0.99**m) / (1 - 0.99))
    ended = uniform["next", "terminated"].reshape(-1)
    assert ended.any() and (later[ended] == 13).all()  # only car 1 ends, at its 13th step
    metrics = core.update()
    assert metrics and all(torch.isfinite(torch.tensor(v)) for v in metrics.values())


def test_torchrls_target_raises_the_discount_to_the_window_length():
    core = LearningCore(AgentConfig(name="ddpg_image", metrics_every=1, **VARIANTS["ddpg_image"]), TINY, seed=0)
    data = chunks_to_transitions(_collect())[:16]
    data["next", "done"] = data["next", "terminated"] | data["next", "truncated"]
    targets = {}
    for m in (1, 3):
        batch = data.clone()
        batch["steps_to_next_obs"] = torch.full((16, 1), m)
        targets[m] = core.ddpg.loss(batch)[1]["target_value"]
    reward = data["next", "reward"].reshape(-1)
    assert torch.allclose(targets[3] - reward, 0.99**2 * (targets[1] - reward), atol=1e-6)
