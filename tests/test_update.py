"""The combined update (learner/core.py) on LaneDrive-shaped data: every variant trains,
rho enters the replay as tau / mu_hat, the refresh switch works, checkpoints resume exactly."""

import copy

import pytest
import torch

from common.config.agent import AgentConfig, ScaleConfig
from common.networks import make_policy
from learner.behaviour import log_mu_hat
from learner.core import LearningCore
from learner.gvf import importance_ratio, log_tau
from learner.replay import expand
from tests.fakes import collect

VARIANTS = {
    "gvf_ddpg": dict(representation="predictive"),
    "gvf_ddpg_g0": dict(representation="predictive", gammas=[0.0]),
    "gvf_ddpg_g095": dict(representation="predictive", gammas=[0.95]),
    "ddpg_image": dict(representation="image"),
    "ddpg_lowdim": dict(representation="lowdim"),
}
TINY = ScaleConfig(name="tiny", conv_channels=[4, 8, 8, 8, 8], gvf_hidden=[32, 32],
                   behaviour_hidden=[32, 16], policy_hidden=[32, 16],
                   image_policy_hidden=[32, 16], batch_size=16, buffer_size=300, warmup=200)


@pytest.fixture(scope="module")
def data():
    return collect(4, 100, seed=0).reshape(-1)  # 400 transitions, time-major per car


def make_core(variant: str, seed: int = 0, **agent_overrides) -> LearningCore:
    torch.set_num_threads(1)
    agent = AgentConfig(name=variant, **{**VARIANTS[variant], "metrics_every": 2,
                                         "lr_actor": 1e-3, **agent_overrides})
    return LearningCore(agent, TINY, seed=seed)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_every_variant_trains_all_its_networks(variant, data):
    core = make_core(variant)
    core.add(data[:100])
    assert not core.ready
    with pytest.raises(RuntimeError, match="warm-up"):
        core.update()
    core.add(data[100:])  # 400 into a ring of 300: evictions
    assert core.ready and len(core.replay) == 300
    if core.predictive:
        core.set_held_out(data[:100])  # car 0's first 100 steps, in time order
    before = {name: copy.deepcopy(m.state_dict()) for name, m in core.nets.modules().items()}
    target_before = core.ddpg.loss_module.target_value_network_params.clone()
    assert core.update() == {}
    metrics = core.update()
    expected = {"losses/actor", "losses/critic", "train/q_mean", "train/q_target_mean"}
    if core.predictive:
        expected |= {"losses/td", "losses/behaviour", "train/rho_bar", "train/rho_clip_rate",
                     "eval/gvf_return_rmse_alpha", "eval/constant_return_rmse_beta"}
    assert expected <= set(metrics), expected - set(metrics)
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())
    for name, module in core.nets.modules().items():
        changed = [not torch.equal(v, before[name][k]) for k, v in module.state_dict().items()]
        assert all(changed), f"{name}: {sum(changed)} of {len(changed)} tensors moved"
    target_after = core.ddpg.loss_module.target_value_network_params
    assert any(not torch.equal(a, b) for a, b in zip(target_after.values(True, True),
                                                     target_before.values(True, True)))
    acting = make_policy(core.agent, TINY)
    acting.load_state_dict(core.policy_state_dict())
    with torch.no_grad():
        assert torch.equal(acting(data[:5]), core.nets.policy(data[:5]))


def test_rho_at_insert_is_tau_over_mu_hat_and_clips_are_counted(data):
    core = make_core("gvf_ddpg", rho_max=20.0)
    batch = data[:64]
    core.add(batch)
    with torch.no_grad():
        logit = core.nets.behaviour(batch["image"], batch["speed"], batch["last_action"],
                                    batch["action"])
    log_ratio = (log_tau(batch["action"], batch["last_action"], core.agent.tau_width)
                 - log_mu_hat(logit, batch["action"]))
    expected = log_ratio.exp().clamp(max=20.0).reshape(-1).double()
    assert torch.allclose(core.replay.rho[:64], expected, rtol=1e-5)
    assert core._rho_clipped == int((log_ratio.exp() > 20.0).sum()) > 0
    assert abs(core.replay.rho_bar - float(expected.mean())) < 1e-9 * float(expected.mean())


def test_baselines_store_rho_one():
    core = make_core("ddpg_image")
    core.add(collect(1, 30, seed=1).reshape(-1))
    assert torch.all(core.replay.rho[:30] == 1.0) and core.replay.rho_bar == 1.0


@pytest.mark.parametrize("refresh", [False, True])
def test_refresh_switch_rewrites_rho_of_the_sampled_batch(refresh, data):
    core = make_core("gvf_ddpg", refresh_rho=refresh)
    core.add(data[:300])
    with torch.no_grad():  # the discriminator has moved on since the insert
        core.nets.behaviour.head[-1].bias += 1.0
    g_before = copy.deepcopy(core.nets.behaviour)
    rho_before = core.replay.rho.clone()
    core.update()
    changed = torch.nonzero(core.replay.rho != rho_before).reshape(-1)
    if not refresh:
        assert changed.numel() == 0
        return
    assert 0 < changed.numel() <= TINY.batch_size
    stored = expand(core.replay.buffer.storage.get(changed))
    with torch.no_grad():
        logit = g_before(stored["image"], stored["speed"], stored["last_action"], stored["action"])
    expected, _ = importance_ratio(
        log_tau(stored["action"], stored["last_action"], core.agent.tau_width),
        log_mu_hat(logit, stored["action"]), core.agent.rho_max)
    assert torch.allclose(core.replay.rho[changed], expected.reshape(-1).double(), rtol=1e-5)
    assert abs(core.replay.rho_bar - float(core.replay.rho[:300].mean())) < 1e-9 * core.replay.rho_bar


def test_checkpoint_resumes_to_identical_updates(data):
    core = make_core("gvf_ddpg")
    core.add(data)
    core.update()
    state = copy.deepcopy(core.state_dict(with_replay=True))
    resumed = make_core("gvf_ddpg", seed=1)  # other weights, replay and generators until loaded
    resumed.load_state_dict(state)
    assert resumed.updates == core.updates and resumed.replay.rho_bar == core.replay.rho_bar
    for _ in range(2):
        core.update()
        resumed.update()
    for name, module in core.nets.modules().items():
        other = resumed.nets.modules()[name].state_dict()
        for key, value in module.state_dict().items():
            assert torch.equal(value, other[key]), (name, key)
