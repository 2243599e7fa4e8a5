"""Networks (common/networks.py) and the agent/scale configs (common/config/agent.py,
conf/agent, conf/scale): the paper's shapes, initialisation and output ranges."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from common.config.agent import AgentConfig, ScaleConfig, check_scale, register
from common.critics import AdvantageCritic, BranchedCritic
from common.layers import PilotNetTrunk
from common.networks import (
    BranchedActor,
    GVFNetwork,
    make_networks,
    make_policy,
    phi_mirror_sign,
)

CONF = Path(__file__).resolve().parents[1] / "conf"
VARIANTS = ["gvf_ddpg", "gvf_ddpg_g0", "gvf_ddpg_g095", "ddpg_image", "ddpg_lowdim"]


def load(variant: str, scale: str) -> tuple[AgentConfig, ScaleConfig]:
    """Compose conf/agent/<variant>.yaml and conf/scale/<scale>.yaml against the schemas."""
    register()
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose(overrides=[f"+agent={variant}", f"+scale={scale}"])
    return OmegaConf.to_object(cfg.agent), OmegaConf.to_object(cfg.scale)


def obs(n: int, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "image": torch.randint(0, 256, (n, 2, 64, 128), dtype=torch.uint8, generator=g),
        "speed": torch.rand(n, 1, generator=g),
        "last_action": torch.rand(n, 2, generator=g),
        "alpha": torch.rand(n, 1, generator=g),
        "beta": torch.rand(n, 1, generator=g),
    }


@pytest.mark.parametrize("scale", ["small", "paper"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_every_config_composes_and_builds_its_networks(variant, scale):
    agent, scale_cfg = load(variant, scale)
    assert isinstance(agent, AgentConfig) and agent.name == variant
    assert scale_cfg.name == scale
    nets = make_networks(agent, scale_cfg)
    with torch.no_grad():
        action = nets.policy(obs(3))
    assert action.shape == (3, 2) and action.abs().max() <= 1.0
    if variant.startswith("gvf"):
        assert nets.gvf.n_predictions == 2 * len(agent.gammas)
        assert nets.behaviour is not None
    else:
        assert nets.gvf is None and nets.behaviour is None


def test_paper_gammas_and_prediction_count():
    agent, _ = load("gvf_ddpg", "paper")
    assert agent.gammas == [0.0, 0.5, 0.9, 0.95, 0.97]
    assert agent.cumulants == ["alpha", "beta"]  # 2 x 5 = 10 predictions (see learner/gvf.py)
    assert load("gvf_ddpg_g0", "small")[0].gammas == [0.0]
    assert load("gvf_ddpg_g095", "small")[0].gammas == [0.95]


def test_pilotnet_trunk_shapes_match_the_paper():
    trunk = PilotNetTrunk([24, 36, 48, 64, 64])
    convs = [m for m in trunk.modules() if isinstance(m, torch.nn.Conv2d)]
    assert [(c.out_channels, c.kernel_size, c.stride) for c in convs] == [
        (24, (5, 5), (2, 2)),
        (36, (5, 5), (2, 2)),
        (48, (5, 5), (2, 2)),
        (64, (3, 3), (1, 1)),
        (64, (3, 3), (1, 1)),
    ]
    assert trunk.out_dim == 64 * 1 * 9  # 64x128 -> 30x62 -> 13x29 -> 5x13 -> 3x11 -> 1x9


def test_gvf_network_layer_sizes():
    gvf = GVFNetwork([24, 36, 48, 64, 64], [512, 384], 10)
    linears = [m for m in gvf.head if isinstance(m, torch.nn.Linear)]
    assert [(layer.in_features, layer.out_features) for layer in linears] == [(576 + 3, 512), (512, 384), (384, 10)]


def test_actor_last_layers_are_near_zero_and_outputs_clipped():
    torch.manual_seed(0)
    actor = BranchedActor(13, [256, 128])
    for branch in actor.branches:
        assert branch[-1].weight.abs().max() <= 1e-3
        assert torch.all(branch[-1].bias == 0)
        assert [layer.out_features for layer in branch if isinstance(layer, torch.nn.Linear)] == [256, 128, 1]
    x = torch.randn(64, 13)
    assert actor(x).abs().max() < 0.05  # the initial policy barely moves
    for branch in actor.branches:
        torch.nn.init.constant_(branch[-1].bias, 5.0)
    assert torch.all(actor(x) == 1.0)
    assert torch.all(BranchedActor(13, [8], squash="tanh")(x).abs() < 1.0)


@pytest.mark.parametrize("variant", ["gvf_ddpg", "ddpg_image"])
@pytest.mark.parametrize("squash", ["clip", "tanh"])
def test_the_scales_speed_init_sets_the_first_speed_actions_and_leaves_the_steering(variant, squash):
    agent, scale = load(variant, "small")
    slow = dataclasses.replace(scale, actor_speed_init=-0.6, actor_squash=squash)
    torch.manual_seed(0)
    policy = make_policy(agent, slow)
    head = policy.actor if variant == "gvf_ddpg" else policy.actor.head
    x = torch.randn(32, head.branches[0][0].in_features)
    out = head(x)
    assert torch.allclose(out[:, 1], torch.full((32,), -0.6), atol=0.02)  # 0.6 v_max, 12 m/s at v_max 20
    assert out[:, 0].abs().max() < 0.05  # the steering's init is the paper's
    out[:, 1].sum().backward()  # inside the clip: the critic can still move the speed either way
    assert head.branches[1][-1].bias.grad.abs().item() > 0
    with pytest.raises(ValueError, match="scale.actor_speed_init must be in"):
        check_scale(dataclasses.replace(scale, actor_speed_init=-1.0))
    with pytest.raises(ValueError, match="scale.actor_speed_hold must be >= 0"):
        check_scale(dataclasses.replace(scale, actor_speed_hold=-1))


@pytest.mark.parametrize("squash", ["clip", "tanh"])
def test_mirror_actor_steers_oddly_and_sets_speed_evenly_under_the_mirror(squash):
    torch.manual_seed(0)
    sign = phi_mirror_sign(10)
    actor = BranchedActor(13, [16, 8], squash=squash, mirror_sign=sign)
    for branch in actor.branches:  # outputs well away from 0 at init, inside the clip
        torch.nn.init.normal_(branch[-1].weight, std=0.3)
        torch.nn.init.constant_(branch[-1].bias, 0.2)
    x = torch.randn(32, 13) * 0.5
    out, mirrored = actor(x), actor(x * sign)
    assert out[:, 0].abs().min() > 0  # a real steering signal, not 0 everywhere
    assert torch.allclose(mirrored[:, 0], -out[:, 0], atol=1e-6)
    assert torch.allclose(mirrored[:, 1], out[:, 1], atol=1e-6)
    centred = x * (sign > 0)  # every prediction and the last steering 0: its own mirror image
    assert torch.all(actor(centred)[:, 0] == 0)
    plain = BranchedActor(13, [16, 8], squash=squash)
    plain.load_state_dict(actor.state_dict(), strict=False)
    assert not torch.allclose(plain(x)[:, 0], out[:, 0])  # the symmetry comes from the construction


def test_mirror_actor_is_built_from_the_scale_and_refused_by_an_actor_without_it():
    agent, scale = load("gvf_ddpg", "small")
    on = dataclasses.replace(scale, mirror_actor=True)
    policy = make_policy(agent, on)
    assert torch.equal(policy.actor.mirror_sign, torch.tensor([-1.0] * 10 + [1.0, -1.0, 1.0]))
    with pytest.raises(RuntimeError, match="mirror_sign"):
        make_policy(agent, dataclasses.replace(scale, mirror_actor=False)).load_state_dict(policy.state_dict())
    image_agent, _ = load("ddpg_image", "small")
    assert "mirror_sign" not in str(list(make_policy(image_agent, on).state_dict()))  # baselines unaffected


@pytest.mark.parametrize("squash", ["clip", "tanh"])
def test_integrating_actor_moves_its_steering_from_the_last_by_at_most_the_increment(squash):
    torch.manual_seed(0)
    actor = BranchedActor(13, [16, 8], squash=squash, steer_increment=0.25)
    x = torch.randn(256, 13)
    x[:, -2] = torch.linspace(-1.0, 1.0, 256)  # the last steering, across its range
    held = actor(x)  # near-zero last layers at init: the steering holds where it was
    assert torch.allclose(held[:, 0], x[:, -2], atol=1e-2)
    for branch in actor.branches:  # outputs far from 0 and past the squash's bounds
        torch.nn.init.normal_(branch[-1].weight, std=3.0)
    out = actor(x)
    change = out[:, 0] - x[:, -2]
    assert change.abs().max() <= 0.25 + 1e-6 and change.abs().max() > 0.2  # bounded, yet it moves
    assert out[:, 0].abs().max() <= 1.0 and out[:, 0].abs().max() == 1.0  # clipped at full lock
    absolute = BranchedActor(13, [16, 8], squash=squash)
    absolute.load_state_dict(actor.state_dict(), strict=False)
    assert torch.allclose(out[:, 1], absolute(x)[:, 1])  # the target speed stays absolute
    inside = (x[:, -2] + 0.25 * absolute(x)[:, 0]).abs() < 1.0  # where no clip at full lock applies
    assert inside.sum() > 100
    assert torch.allclose(change[inside], 0.25 * absolute(x)[inside, 0], atol=1e-6)  # the output is a change


def test_integrating_mirror_actor_stays_odd_and_is_refused_by_an_absolute_actor():
    agent, scale = load("gvf_ddpg", "small")
    on = dataclasses.replace(scale, mirror_actor=True, steer_increment=0.25)
    policy = make_policy(agent, on)
    actor = policy.actor
    for branch in actor.branches:
        torch.nn.init.normal_(branch[-1].weight, std=0.3)
    sign = phi_mirror_sign(10)
    x = torch.randn(64, 13) * 0.5
    out, mirrored = actor(x), actor(x * sign)
    assert torch.allclose(mirrored[:, 0], -out[:, 0], atol=1e-6)
    assert torch.allclose(mirrored[:, 1], out[:, 1], atol=1e-6)
    with pytest.raises(RuntimeError, match="steer_increment"):
        make_policy(agent, dataclasses.replace(on, steer_increment=0.0)).load_state_dict(policy.state_dict())
    with pytest.raises(ValueError, match="steer_increment"):
        BranchedActor(13, [16, 8], steer_increment=-0.1)


def test_critic_norm_bounds_q_where_the_plain_critic_extrapolates():
    torch.manual_seed(0)
    normed, plain = BranchedCritic(13, [16, 8], norm=True), BranchedCritic(13, [16, 8])
    x, a = torch.randn(64, 13), torch.randn(64, 2)
    q = {(c, k): c(x * k, a * k) for c in (normed, plain) for k in (1e2, 1e4)}
    # LayerNorm is scale-invariant: past the first layer's bias Q stops moving with the input's size
    assert (q[normed, 1e4] - q[normed, 1e2]).abs().max() < 1e-2
    assert (q[plain, 1e4] - q[plain, 1e2]).abs().max() > 10.0  # the plain MLP grows with it


def test_critic_norm_is_built_from_the_scale_for_every_variant():
    for variant in ("gvf_ddpg", "ddpg_image"):
        agent, scale = load(variant, "small")
        on = make_networks(agent, dataclasses.replace(scale, critic_norm=True)).critic
        off = make_networks(agent, scale).critic
        assert any(isinstance(m, torch.nn.LayerNorm) for m in on.modules())
        assert not any(isinstance(m, torch.nn.LayerNorm) for m in off.modules())


def test_critic_is_the_sum_of_its_branches():
    torch.manual_seed(0)
    critic = BranchedCritic(13, [16, 8])
    x, a = torch.randn(5, 13), torch.randn(5, 2)
    xa = torch.cat([x, a], -1)
    expected = critic.branches[0](xa) + critic.branches[1](xa)
    assert torch.allclose(critic(x, a), expected)


def test_critic_without_the_last_action_ignores_phis_tail_and_reads_the_action():
    agent, scale = load("gvf_ddpg", "small")
    torch.manual_seed(0)
    critic = make_networks(agent, dataclasses.replace(scale, critic_last_action=False)).critic
    n_phi = make_networks(agent, scale).policy.gvf.n_predictions + 3  # phi: predictions, speed, last action
    x, a = torch.randn(6, n_phi), torch.randn(6, 2)
    other_last = x.clone()
    other_last[:, -2:] = torch.randn(6, 2)  # phi's last action: steering, target speed
    assert torch.equal(critic(other_last, a), critic(x, a))
    assert not torch.allclose(critic(x, a + 0.5), critic(x, a))
    assert critic.branches[0][0].in_features == n_phi - 2 + 2  # predictions and speed, then the action
    full = make_networks(agent, scale).critic  # the paper's: phi's every entry
    assert not torch.allclose(full(other_last, a), full(x, a))


def test_advantage_critic_is_the_value_at_the_policys_action_and_moves_with_the_action_elsewhere():
    agent, scale = load("gvf_ddpg", "small")
    torch.manual_seed(0)
    # the plain actor: the mirror actor's steering bias cancels by construction, so it gets no gradient
    nets = make_networks(agent, dataclasses.replace(scale, critic_advantage=True, mirror_actor=False))
    critic, actor = nets.critic, nets.actor
    assert isinstance(critic, AdvantageCritic)
    n_phi = nets.policy.gvf.n_predictions + 3
    x = torch.randn(6, n_phi)
    with torch.no_grad():
        at_policy = actor(x)
        assert torch.allclose(critic(x, at_policy), critic.value(x), atol=1e-6)  # Q(x, pi(x)) = V(x)
        assert not torch.allclose(critic(x, at_policy + 0.3), critic.value(x))
    # the actor's gradient flows through A(x, a) only, and the critic never registers the actor
    a = actor(x)
    critic(x, a).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in actor.parameters() if p.requires_grad)
    assert not any(name.startswith("_policy") for name, _ in critic.named_parameters())
    assert set(critic.state_dict()) == {k for k in critic.state_dict() if k.split(".")[0] in ("value", "advantage")}


def test_advantage_critics_twin_shares_the_actor_and_an_uncentred_one_is_refused():
    import copy

    actor, critic = BranchedActor(7, [8]), AdvantageCritic(7, [8])
    with pytest.raises(RuntimeError, match="centre_on"):
        critic(torch.randn(2, 7), torch.zeros(2, 2))
    twin = copy.deepcopy(critic.centre_on(actor))
    assert twin._policy.module is actor  # the twin centres on the live actor, not a frozen copy
    for module in twin.modules():  # TD3 re-initialises the twin: the actor must not be touched
        if hasattr(module, "reset_parameters"):
            module.reset_parameters()
    assert actor.branches[0][-1].weight.abs().max() <= 1e-3  # still its near-zero initialisation


@pytest.mark.parametrize("variant", ["gvf_ddpg", "ddpg_lowdim"])
def test_broadcast_weights_rebuild_the_same_policy_on_the_actor_side(variant):
    agent, scale = load(variant, "small")
    torch.manual_seed(0)
    learner_side = make_networks(agent, scale)
    torch.manual_seed(1)
    actor_side = make_policy(agent, scale)
    actor_side.load_state_dict(learner_side.policy.state_dict())
    batch = obs(4)
    with torch.no_grad():
        expected = learner_side.policy(batch)
        assert torch.equal(actor_side(batch), expected)
        single = actor_side({k: v[1] for k, v in batch.items()})
    assert single.shape == (2,) and torch.allclose(single, expected[1], atol=1e-6)


def test_lowdim_policy_reads_alpha_and_beta():
    agent, scale = load("ddpg_lowdim", "small")
    torch.manual_seed(0)
    policy = make_policy(agent, scale)
    for branch in policy.actor.head.branches:  # make the output sensitive at init
        torch.nn.init.normal_(branch[-1].weight)
    batch = obs(4)
    moved = dict(batch, alpha=batch["alpha"] + 1.0)
    with torch.no_grad():
        assert not torch.allclose(policy(batch), policy(moved))


def test_common_imports_neither_learner_nor_actors():
    code = (
        "import sys, common.networks, common.config.agent; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('learner', 'actors')]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=CONF.parent)
