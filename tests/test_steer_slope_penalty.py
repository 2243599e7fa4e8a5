"""The critic's steering-slope penalty (learner/ddpg.py `steer_slope_penalty`, `scale.critic_steer_penalty`):
it shrinks a slope the data do not support, keeps one they do, and trains only the critics."""

import dataclasses

import pytest
import torch
from tensordict import TensorDict

from common.config.agent import check_scale
from common.critics import BranchedCritic
from common.networks import BranchedActor
from learner.ddpg import DDPG
from tests.test_td3_target import TINY


def make(td3: bool, penalty: float, after: int = 0) -> DDPG:
    torch.manual_seed(0)
    actor = BranchedActor(3, [32, 32], n_actions=2)
    critic = BranchedCritic(3, [64, 64], n_actions=2)
    return DDPG(
        actor,
        critic,
        actor_in_keys=["phi"],
        critic_in_keys=["phi", "action"],
        lr_actor=0.0,
        lr_critic=3e-3,
        td3=td3,
        actor_delay=1,
        steer_slope_penalty=penalty,
        steer_slope_penalty_after=after,
    )


def one_step_batch(steer_weight: float, n: int = 48, seed: int = 0) -> TensorDict:
    """One-step episodes (the target is the reward): r = steer_weight * steering + noise that
    depends on nothing the critic sees, so with few items a free critic fits slopes into the noise."""
    g = torch.Generator().manual_seed(seed)
    phi, action = torch.randn(n, 3, generator=g), torch.rand(n, 2, generator=g) * 2 - 1
    reward = steer_weight * action[:, :1] + torch.randn(n, 1, generator=g)
    done = torch.ones(n, 1, dtype=torch.bool)
    return TensorDict(
        {"phi": phi, "action": action, "next": {"phi": phi, "reward": reward, "done": done, "terminated": done}},
        [n],
    )


def steer_slopes(ddpg: DDPG, batch: TensorDict) -> torch.Tensor:
    return ddpg.action_gradient(batch)[1][:, 0]


@pytest.mark.parametrize("td3", [False, True])
def test_the_penalty_shrinks_a_steering_slope_the_data_do_not_support(td3):
    batch = one_step_batch(steer_weight=0.0)
    slopes = {}
    for penalty in (0.0, 1.0):
        ddpg = make(td3, penalty)
        for _ in range(300):
            ddpg.update(batch)
        slopes[penalty] = steer_slopes(ddpg, batch).abs().mean().item()
    print(f"mean abs dQ/dsteer on noise: free {slopes[0.0]:.3f}, penalised {slopes[1.0]:.3f}")
    assert slopes[1.0] < 0.5 * slopes[0.0]


def test_the_penalty_keeps_the_sign_of_a_slope_the_data_support_on_most_states():
    """r = 2 steering + noise: the penalised critic's slope stays positive on average and at most
    states. It is a ridge on the slope: measured on this problem (600 updates), the share of states
    with the right sign falls from 0.96 (free) to 0.87 at 0.1 and 0.68 at 1.0 (signal and noise
    shrink together)."""
    ddpg = make(True, 0.1)
    batch = one_step_batch(steer_weight=2.0, n=256)
    for _ in range(300):
        ddpg.update(batch)
    slopes = steer_slopes(ddpg, batch)
    assert (slopes > 0).float().mean() > 0.75, slopes
    assert 0.4 < slopes.mean() < 2.5, slopes.mean()


@pytest.mark.parametrize("td3", [False, True])
def test_the_penalty_reaches_every_critic_and_not_the_actor(td3):
    ddpg = make(td3, 1.0)
    batch = one_step_batch(steer_weight=0.0)
    ddpg.zero_grad()
    _, out = ddpg.loss(batch)
    out["loss_steer_slope"].backward()
    assert out["loss_steer_slope"] > 0
    critics = ddpg.loss_module.qvalue_network_params if td3 else ddpg.loss_module.value_network_params
    # weights only: with ReLUs dQ/da does not depend on the biases (a zero second derivative)
    weights = [p.grad for key, p in critics.items(True, True) if key[-1] == "weight"]
    assert weights and all(g is not None and g.abs().sum() > 0 for g in weights)
    if td3:  # both twins, stacked on the first dimension
        assert all((g.flatten(1).abs().sum(1) > 0).all() for g in weights)
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in ddpg.actor.parameters())


def test_a_delayed_penalty_starts_after_that_many_updates_and_resumes_there():
    batch = one_step_batch(steer_weight=0.0)
    ddpg = make(True, 1.0, after=3)
    charged = []
    for _ in range(5):
        charged.append("loss_steer_slope" in ddpg.update(batch).keys())
    assert charged == [False, False, False, True, True]
    resumed = make(True, 1.0, after=3)
    resumed.load_state_dict(ddpg.state_dict())
    assert "loss_steer_slope" in resumed.update(batch).keys()


def test_a_negative_penalty_is_refused_naming_the_field():
    with pytest.raises(ValueError, match="scale.critic_steer_penalty must be >= 0"):
        check_scale(dataclasses.replace(TINY, critic_steer_penalty=-0.1))
    with pytest.raises(ValueError, match="scale.critic_steer_penalty_after must be >= 0"):
        check_scale(dataclasses.replace(TINY, critic_steer_penalty_after=-1))
    with pytest.raises(ValueError, match="steer_slope_penalty"):
        make(True, -1.0)


def test_the_learning_core_applies_and_reports_the_penalty_from_the_scale():
    from common.config.agent import AgentConfig
    from learner.core import LearningCore
    from tests.core_fixtures import TINY as CORE_TINY
    from tests.core_fixtures import lanedrive_data

    data = lanedrive_data()
    scale = dataclasses.replace(CORE_TINY, td3=True, td3_actor_delay=1, critic_steer_penalty=0.5)
    core = LearningCore(AgentConfig(name="gvf_ddpg", metrics_every=1), scale, seed=0)
    core.add(data[:300])
    metrics = [core.update() for _ in range(3)]
    assert core.ddpg.steer_slope_penalty == 0.5
    assert all(m["losses/steer_slope"] > 0 for m in metrics if m)
    assert any(metrics)
