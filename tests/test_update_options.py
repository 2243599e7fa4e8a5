"""Options of the combined update beyond the paper (learner/core.py): acting with the target
actor, reward scale, crash penalty, offset weight, TD3, the crash memory (and leaving it out of the
actor's loss); each off by default."""

import copy
import dataclasses

import pytest
import torch

from common.config.agent import AgentConfig
from learner.core import LearningCore
from learner.ddpg_batch import phi_batch
from learner.replay import FROM_CRASHES
from tests.core_fixtures import TINY, lanedrive_data


@pytest.fixture(scope="module")
def data():
    return lanedrive_data()


def test_act_with_target_broadcasts_the_polyak_averaged_actor(data):
    scale = dataclasses.replace(TINY, act_with_target=True)
    core = LearningCore(AgentConfig(name="gvf_ddpg", lr_actor=1e-2, metrics_every=100), scale, seed=0)
    core.add(data[:300])
    for _ in range(5):
        core.update()
    sent, online = core.policy_state_dict(), core.nets.policy.state_dict()
    target = core.ddpg.loss_module.target_actor_network_params
    key = "branches.0.0.weight"
    assert torch.equal(sent[f"actor.{key}"], target[("module", *key.split("."))])
    assert not torch.equal(sent[f"actor.{key}"], online[f"actor.{key}"])
    assert all(torch.equal(sent[k], online[k]) for k in online if k.startswith("gvf."))  # no target GVF


def test_reward_scale_scales_the_critics_target(data, monkeypatch):
    seen = []
    for reward_scale in (1.0, 0.01):
        core = LearningCore(
            AgentConfig(name="ddpg_image", metrics_every=1),
            dataclasses.replace(TINY, reward_scale=reward_scale),
            seed=0,
        )
        core.add(data[:300])
        loss = core.ddpg.loss
        monkeypatch.setattr(
            core.ddpg, "loss", lambda batch: (seen.append(batch["next", "reward"].clone()), loss(batch))[1]
        )
        core.update()
    assert torch.allclose(seen[1], 0.01 * seen[0])
    assert seen[0].abs().max() > 0


@pytest.mark.parametrize("agent", ["gvf_ddpg", "ddpg_image"])
def test_crash_penalty_lowers_only_the_reward_of_lane_exits(data, monkeypatch, agent):
    data = data[:300].clone()
    data["next", "terminated"][::5] = True  # some lane exits in every minibatch
    seen = []
    for penalty in (0.0, 2.5):
        scale = dataclasses.replace(TINY, crash_penalty=penalty, reward_scale=0.5)
        core = LearningCore(AgentConfig(name=agent, metrics_every=1), scale, seed=0)
        core.add(data)
        loss = core.ddpg.loss
        monkeypatch.setattr(
            core.ddpg, "loss", lambda b: (seen.append(b["next"].select("reward", "terminated").clone()), loss(b))[1]
        )
        core.update()
    base, penalised = seen
    assert torch.equal(base["terminated"], penalised["terminated"]) and base["terminated"].any()
    crashed = base["terminated"]
    assert torch.allclose(penalised["reward"][crashed], base["reward"][crashed] - 0.5 * 2.5)
    assert torch.equal(penalised["reward"][~crashed], base["reward"][~crashed])


def test_offset_weight_charges_the_reached_states_offset_as_the_envs_reward_would_at_that_weight(data):
    from learner.ddpg_batch import ddpg_reward

    nxt = data[:300]["next"]
    assert (nxt["alpha"].abs() > 0.05).any()  # some off-centre steps to charge
    for weight in (1.0, 3.0):
        reward = ddpg_reward(nxt, dataclasses.replace(TINY, offset_weight=weight), discount=0.99)
        # LaneDrive's reward with the offset term weighted: v/v_max (cos beta - weight |alpha|)
        expected = nxt["speed"] * (nxt["beta"].cos() - weight * nxt["alpha"].abs())
        assert torch.allclose(reward, expected, atol=1e-5)


def test_td3_option_steps_the_actor_every_second_update_with_twin_critics_and_resumes(data):
    scale = dataclasses.replace(TINY, td3=True, td3_actor_delay=2)
    core = LearningCore(AgentConfig(name="gvf_ddpg", lr_actor=1e-3, metrics_every=2), scale, seed=0)
    core.add(data[:300])
    twins = core.ddpg.loss_module.qvalue_network_params
    first = twins["module", "branches", "0", "0", "weight"]
    assert first.shape[0] == 2 and not torch.allclose(first[0], first[1])  # two critics, two starts
    actor = [copy.deepcopy(core.nets.actor.state_dict())]
    for _ in range(4):
        core.update()
        actor.append(copy.deepcopy(core.nets.actor.state_dict()))
    moved = [any(not torch.equal(a[k], b[k]) for k in a) for a, b in zip(actor, actor[1:])]
    assert moved == [False, True, False, True]
    resumed = LearningCore(AgentConfig(name="gvf_ddpg", lr_actor=1e-3, metrics_every=2), scale, seed=1)
    resumed.load_state_dict(copy.deepcopy(core.state_dict(with_replay=True)))
    for c in (core, resumed):
        torch.manual_seed(5)  # torchrl draws the target-smoothing noise from the global generator
        c.update()
        c.update()
    assert all(torch.equal(v, resumed.nets.actor.state_dict()[k]) for k, v in core.nets.actor.state_dict().items())
    assert (core.ddpg.loss_module.qvalue_network_params == resumed.ddpg.loss_module.qvalue_network_params).all()


def test_the_crash_memory_feeds_the_uniform_batch_after_the_replay_evicted_its_crashes(data):
    scale = dataclasses.replace(TINY, crash_memory=40)
    core = LearningCore(AgentConfig(name="gvf_ddpg", metrics_every=1), scale, seed=0)
    calm, crash = data[1:], data[:1].clone()
    crash["next", "reward"] = torch.full((1, 1), -7.0)  # marks the one crash transition
    crash["next", "terminated"] = torch.ones(1, 1, dtype=torch.bool)
    core.add(crash)
    core.add_crashes(crash)
    core.add(calm[:300])  # the ring of 300 evicted the crash
    assert not bool((core.replay.buffer.storage.get(torch.arange(300))["reward"] == -7).any())
    seen = [core._uniform()["next", "reward"] for _ in range(40)]  # 640 draws, 1/301 each: ~2 crashes
    assert any(bool((r == -7).any()) for r in seen)
    assert core.update()["train/crash_memory_size"] == 1.0
    state = core.state_dict(with_replay=True)
    resumed = LearningCore(AgentConfig(name="gvf_ddpg"), scale, seed=0)
    resumed.load_state_dict(state)
    assert len(resumed.crashes) == 1
    assert LearningCore(AgentConfig(name="gvf_ddpg"), TINY).crashes is None  # 0: the paper's single replay


@pytest.mark.parametrize("td3", [False, True])
def test_without_the_crash_memory_in_the_actor_its_items_train_the_critic_and_not_the_actor(data, td3):
    scale = dataclasses.replace(TINY, crash_memory=40, crash_memory_actor=False, td3=td3)
    core = LearningCore(AgentConfig(name="gvf_ddpg", metrics_every=1), scale, seed=0)
    crash = data[:30].clone()
    crash["next", "reward"] = torch.full((30, 1), -7.0)  # marks the crash memory's copies
    core.add(data[30:330])
    core.add_crashes(crash)
    uniform = core._uniform()
    marked = uniform[FROM_CRASHES]
    assert torch.equal(marked, uniform["next", "reward"].reshape(-1) == -7.0) and marked.any()
    batch = phi_batch(core.nets.gvf, uniform, uniform["next", "reward"])

    def gradients(ddpg_batch):
        core._zero_grad()
        core.ddpg.loss(ddpg_batch)[0].backward()
        return [p.grad.clone() for p in core.nets.actor.parameters()], [
            p.grad.clone() for p in core.ddpg.critic_optimizer.param_groups[0]["params"]
        ]

    actor, critic = gradients(batch)
    torch.manual_seed(0)  # the same target-smoothing noise for the critics' two losses
    critic = gradients(batch)[1]
    unmarked = batch.exclude(FROM_CRASHES)  # every item, as the default trains the actor
    actor_all = gradients(unmarked)[0]
    actor_calm = gradients(unmarked[~marked])[0]
    torch.manual_seed(0)
    critic_all = gradients(unmarked)[1]
    assert all(torch.allclose(a, b, atol=1e-6) for a, b in zip(actor, actor_calm))
    assert not all(torch.allclose(a, b, atol=1e-6) for a, b in zip(actor, actor_all))
    assert all(torch.allclose(a, b, atol=1e-6) for a, b in zip(critic, critic_all))  # the critic keeps them


@pytest.mark.parametrize("variant", ["gvf_ddpg", "ddpg_image"])
def test_the_speed_hold_keeps_every_variants_speed_branch_for_its_updates(data, variant):
    scale = dataclasses.replace(TINY, actor_speed_hold=4, td3=False)
    core = LearningCore(AgentConfig(name=variant, lr_actor=1e-2, metrics_every=100), scale, seed=0)
    core.add(data[:300])
    branch = core.ddpg.speed_branch
    before = [p.clone() for p in branch.parameters()]
    while core.ddpg.steps < 4:
        core.update()
    assert all(torch.equal(a, b) for a, b in zip(before, branch.parameters()))
    core.update()
    assert not all(torch.equal(a, b) for a, b in zip(before, branch.parameters()))
