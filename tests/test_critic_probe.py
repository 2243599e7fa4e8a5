"""critic_probe: the critic read along a policy's own drives, before its crashes and on its laps."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from actors.evaluation.critic_probe import (
    discounted_returns,
    mirrored_probe,
    probe_steps,
    recording_policy,
    summarise,
    twin_critics,
)
from actors.evaluation.evaluate import evaluate
from common.config.agent import AgentConfig
from common.networks import make_policy
from learner.core import LearningCore
from tests.core_fixtures import TINY, VARIANTS


def test_returns_are_discounted_to_the_drives_end():
    assert np.allclose(discounted_returns(np.array([1.0, 1.0, 1.0]), 0.5), [1.75, 1.5, 1.0])


class PeakedCritic(torch.nn.Module):
    """Q(x, a) = -(a_speed - x0)^2 + a_steer: the best target speed is x0; Q rises steering left."""

    def forward(self, x, a):
        return -((a[:, 1:] - x[:, :1]) ** 2) + a[:, :1]


def test_the_sweep_finds_the_critics_best_speed_and_the_gradients_sign():
    x = torch.tensor([[-0.5], [0.3], [0.9]])
    action = torch.tensor([[0.2, 0.0], [0.1, 0.8], [-0.4, 0.9]])
    probe = probe_steps(PeakedCritic(), x, action)
    assert np.allclose(probe["best_speed_action"], [-0.5, 0.3, 0.9], atol=1e-6)
    assert np.allclose(probe["q"], [-0.05, -0.15, -0.4], atol=1e-6)
    assert list(np.sign(probe["dq_dspeed"])) == [-1.0, -1.0, 0.0]  # too fast, too fast, at the peak
    assert np.allclose(probe["dq_dsteer"], 1.0)


def test_the_mirrored_probe_reads_the_critic_at_the_mirrored_action_and_the_actors_asymmetry():
    x_m = torch.tensor([[0.3, -0.2], [0.9, 0.5]])
    action = torch.tensor([[0.2, 0.4], [-0.5, 0.1]])
    equivariant = SimpleNamespace(actor=lambda x: torch.stack([torch.tensor([-0.2, 0.5]), x[:, 1]], 1))
    out = mirrored_probe(equivariant, PeakedCritic(), x_m, action)
    assert np.allclose(out["dq_dsteer_mirrored"], 1.0)  # Q rises steering left wherever it is read
    assert np.allclose(out["steer_asymmetry"], 0.0)  # it steers the mirror of the step's steering
    one_sided = SimpleNamespace(actor=lambda x: torch.full((len(x), 2), 0.2))
    assert np.allclose(mirrored_probe(one_sided, PeakedCritic(), x_m, action)["steer_asymmetry"], [0.4, -0.3])


def test_windows_pool_pre_crash_and_lapping_steps():
    n = 40
    crash = {"metrics": {"lap_completed": 0.0}, "terminated": True, "ddpg_reward": np.ones(n)}
    lap = {"metrics": {"lap_completed": 1.0}, "terminated": False, "ddpg_reward": np.ones(n)}
    # the lap: 10 steps 0.5 left of the centre (Q rises steering further left: away), then centred
    alpha = np.where(np.arange(n) < 10, 0.5, 0.0).astype(np.float32)
    crash["trace"] = {"action": np.zeros((n, 2), np.float32), "alpha": np.full(n, -0.6, np.float32)}
    lap["trace"] = {"action": np.zeros((n, 2), np.float32), "alpha": alpha}
    probe = {
        "q": np.full(n, 10.0),
        "best_speed_action": np.full(n, -1.0),
        "dq_dspeed": np.full(n, 2.0),
        "dq_dsteer": np.full(n, 0.5),
        "dq_dsteer_mirrored": np.full(n, 0.5),  # at -alpha, Q rising to the left points to the centre there
        "steer_asymmetry": np.full(n, -0.2),
    }
    out = summarise([crash, lap], [probe, probe], discount=0.0, v_max=20.0, before=(30, 5), horizon=10)
    assert out["pre_crash"]["steps"] == 25 and out["lapping"]["steps"] == 30
    for part in out.values():  # discount 0: G = 1 at every step; -1 of the action is 5 m/s below 0
        assert part["q_minus_return"] == pytest.approx(9.0) and part["preferred_speed"] == pytest.approx(-5.0)
        assert part["slower_preferred"] == 1.0 and part["dq_dspeed_positive"] == 1.0
    # right of the centre before the crash, Q rising to the left: every step points to the centre
    assert out["pre_crash"]["off_centre_steps"] == 25 and out["pre_crash"]["to_centre"] == 1.0
    assert out["lapping"]["off_centre_steps"] == 10 and out["lapping"]["to_centre"] == 0.0
    assert out["lapping"]["to_centre_mirrored"] == 1.0 and out["pre_crash"]["to_centre_mirrored"] == 0.0
    assert out["lapping"]["steer_asymmetry"] == pytest.approx(0.2)
    older = {k: v for k, v in probe.items() if k not in ("dq_dsteer_mirrored", "steer_asymmetry")}  # a cached probe
    assert summarise([lap], [older], discount=0.0, v_max=20.0, horizon=10)["lapping"]["to_centre_mirrored"] is None
    assert out["lapping"]["mean_alpha"] == pytest.approx(5 / 30) and out["lapping"]["mean_abs_alpha"] == pytest.approx(
        5 / 30
    )


def test_the_recorded_phi_and_actions_are_the_drives_own():
    torch.manual_seed(0)
    policy = make_policy(AgentConfig(name="gvf_ddpg", **VARIANTS["gvf_ddpg"]), dataclasses.replace(TINY)).eval()
    record = []
    drives = evaluate(recording_policy(policy, record), tracks=["sage"], max_steps=30)
    assert len(drives) == 2 and len(record) == max(len(d["trace"]["reward"]) for d in drives)
    for i, drive in enumerate(drives):
        recorded = np.stack([record[t][1][i].numpy() for t in range(len(drive["trace"]["action"]))])
        assert np.array_equal(recorded, drive["trace"]["action"])
        assert record[0][0].shape == (2, policy.gvf.n_predictions + 3)  # phi: predictions, speed, last action
        assert record[0][2].shape == record[0][0].shape and not torch.equal(record[0][2], record[0][0])


def test_every_twin_critic_is_read_from_a_checkpoint_in_its_stacked_order():
    torch.manual_seed(0)
    agent, scale = AgentConfig(name="gvf_ddpg", **VARIANTS["gvf_ddpg"]), dataclasses.replace(TINY, td3=True)
    core = LearningCore(agent, scale, seed=0)
    critics = twin_critics({"core": core.state_dict()}, agent, scale)
    qnet, stacked = core.ddpg.critics()
    assert len(critics) == 2
    x, a = torch.randn(5, critics[0].reads), torch.rand(5, 2) * 2 - 1
    with torch.no_grad():
        for critic, params in zip(critics, stacked, strict=True):
            with params.to_module(qnet):
                expected = qnet.module(x, a)
            assert torch.allclose(critic(x, a), expected)
        assert not torch.allclose(critics[0](x, a), critics[1](x, a))  # two critics, not one read twice
