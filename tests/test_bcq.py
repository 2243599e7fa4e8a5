"""BCQ (learner/bcq.py): on a fixed data set it picks the best action the data supports, where
an unconstrained actor on the same learned critic leaves the data; and its torchrl plumbing."""

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from learner.bcq import make_bcq

# A continuing bandit: the state s = (c, u1, u2) never changes (discount 0.5); c = +-1 says
# which goal the reward r = -||a - (c, 1)||^2 pulls toward, u is a nuisance. The data's
# actions sit near two modes only, both far from either goal.
MODES = torch.tensor([[-0.6, -0.6], [0.6, -0.6]])
DATA_NOISE = 0.05
DISCOUNT = 0.5


def reward(s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
    goal = torch.stack([s[:, 0], torch.ones(len(s))], -1)
    return -(a - goal).pow(2).sum(-1, keepdim=True)


def dataset(n: int, gen: torch.Generator, terminated: bool = False) -> TensorDict:
    c = torch.randint(0, 2, (n, 1), generator=gen).float() * 2 - 1
    s = torch.cat([c, torch.rand(n, 2, generator=gen) * 2 - 1], -1)
    a = (MODES[torch.randint(0, 2, (n,), generator=gen)] + DATA_NOISE * torch.randn(n, 2, generator=gen)).clamp(-1, 1)
    flag = torch.full((n, 1), terminated)
    nxt = {"observation": s.clone(), "reward": reward(s, a), "done": flag, "terminated": flag.clone()}
    return TensorDict({"observation": s, "action": a, "next": nxt}, [n])


def probe_states(c: float) -> torch.Tensor:
    u = torch.linspace(-0.9, 0.9, 5)
    return torch.stack([torch.full((5,), c), u, u.flip(0)], -1)


def best_mode(c: float) -> torch.Tensor:
    """The data mode with the higher true reward: (0.6, -0.6) for c = +1, (-0.6, -0.6) for c = -1."""
    s = probe_states(c)[:1]
    return MODES[torch.cat([reward(s, m[None]) for m in MODES]).argmax()]


@pytest.fixture(scope="module")
def trained():
    torch.set_num_threads(1)
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    data = dataset(2048, gen)
    # small nets and a larger step than the paper's 1e-4, so that training takes seconds
    bcq = make_bcq(3, hidden=(64,), lr=3e-3, discount=DISCOUNT, tau=0.05)
    for _ in range(600):
        bcq.update(data[torch.randint(0, len(data), (256,), generator=gen)])
    return bcq


def unconstrained_actor(bcq, steps: int = 300) -> nn.Module:
    """A DDPG-style deterministic actor trained to maximise BCQ's learned Q1, nothing keeping it near the data."""
    torch.manual_seed(1)
    actor = nn.Sequential(nn.Linear(3, 64), nn.ReLU(), nn.Linear(64, 2), nn.Tanh())
    opt = torch.optim.Adam(actor.parameters(), lr=1e-2)
    critic = bcq.loss.qvalue_network
    critic.requires_grad_(False)
    states = torch.cat([probe_states(1.0), probe_states(-1.0)])
    for _ in range(steps):
        opt.zero_grad()
        (-critic.q1(states, actor(states)).mean()).backward()
        opt.step()
    critic.requires_grad_(True)
    return actor


@pytest.mark.parametrize("c", [1.0, -1.0])
def test_bcq_picks_the_best_action_the_data_supports(trained, c):
    a = trained.loss.act(probe_states(c))
    assert a.shape == (5, 2)
    assert (a - best_mode(c)).norm(dim=-1).max() < 0.2, a  # the modes are 1.2 apart


@pytest.mark.parametrize("c", [1.0, -1.0])
def test_an_unconstrained_actor_on_the_same_critic_leaves_the_data(trained, c):
    actor = unconstrained_actor(trained)
    with torch.no_grad():
        a = actor(probe_states(c))
    assert (a[:, None] - MODES[None]).norm(dim=-1).min() > 0.3, a


def test_bcq_values_its_action_at_the_true_value(trained):
    """Q(s, a) = r(s, a) / (1 - discount) when the policy keeps choosing a: the bootstrap
    through the best of n in-support samples neither drops nor inflates the future."""
    s = torch.cat([probe_states(1.0), probe_states(-1.0)])
    a = trained.loss.act(s)
    with torch.no_grad():
        q = trained.loss.qvalue_network.q1(s, a)
    true = reward(s, a).squeeze(-1) / (1 - DISCOUNT)
    assert (q - true).abs().mean() < 0.5, (q, true)  # r alone would be ~2.6 off


def test_act_takes_one_state_or_a_batch_and_stays_in_the_box():
    bcq = make_bcq(11)  # d_s of GVF-BCQ: 8 predictions + last action (2) + speed
    one, batch = bcq.loss.act(torch.randn(11)), bcq.loss.act(torch.randn(4, 11))
    assert one.shape == (2,) and batch.shape == (4, 2)
    assert batch.abs().max() <= 1.0


def _flat(params) -> torch.Tensor:
    return torch.cat([p.flatten() for p in params.values(True, True)])


def _grads(module) -> bool:
    return any(p.grad is not None and p.grad.abs().sum() > 0 for p in module.parameters())


@pytest.mark.parametrize("loss_name, owner", [("loss_vae", "vae"), ("loss_qvalue", "qvalue"), ("loss_actor", "actor")])
def test_each_loss_reaches_only_its_own_network(loss_name, owner):
    torch.manual_seed(0)
    bcq = make_bcq(3, hidden=(16,))
    bcq.loss(dataset(32, torch.Generator().manual_seed(0)))[loss_name].backward()
    nets = {"vae": bcq.loss.vae_network, "qvalue": bcq.loss.qvalue_network, "actor": bcq.loss.actor_network}
    assert {name: _grads(net) for name, net in nets.items()} == {name: name == owner for name in nets}


def test_terminal_targets_are_the_reward():
    torch.manual_seed(0)
    bcq = make_bcq(3, hidden=(16,))
    for terminated in (True, False):
        data = dataset(64, torch.Generator().manual_seed(0), terminated=terminated)
        out = bcq.loss(data)
        is_reward = torch.isclose(out["target_value"], data["next", "reward"].mean())
        assert bool(is_reward) == terminated


def test_soft_update_moves_the_targets_behind_the_online_networks():
    torch.manual_seed(0)
    bcq = make_bcq(3, hidden=(16,), lr=1e-2, tau=0.1)
    loss = bcq.loss
    start = {name: getattr(loss, name).clone() for name in ("actor_network_params", "qvalue_network_params")}
    assert torch.equal(_flat(loss.target_qvalue_network_params), _flat(start["qvalue_network_params"]))
    data = dataset(64, torch.Generator().manual_seed(0))
    for _ in range(20):
        bcq.update(data)
    for name, before in start.items():
        online_moved = (_flat(getattr(loss, name)) - _flat(before)).norm()
        target_moved = (_flat(getattr(loss, "target_" + name)) - _flat(before)).norm()
        assert 0 < target_moved < online_moved, name


def test_set_keys_reads_the_state_from_another_key():
    bcq = make_bcq(3, hidden=(16,))
    bcq.loss.set_keys(observation="phi")
    data = dataset(8, torch.Generator().manual_seed(0))
    data.rename_key_("observation", "phi")
    data.rename_key_(("next", "observation"), ("next", "phi"))
    assert "phi" in bcq.loss.in_keys and ("next", "phi") in bcq.loss.in_keys
    assert torch.isfinite(bcq.loss(data)["loss_qvalue"])


def test_the_policy_copy_acts_as_the_loss_does():
    torch.manual_seed(0)
    bcq = make_bcq(3, hidden=(16,))
    policy = bcq.loss.policy()
    s = torch.randn(6, 3)
    torch.manual_seed(1)
    a = bcq.loss.act(s)
    torch.manual_seed(1)
    assert torch.equal(policy(s), a)
    bcq.update(dataset(32, torch.Generator().manual_seed(0)))  # a copy: the learner moves on alone
    torch.manual_seed(1)
    assert torch.equal(policy(s), a)


def test_e2e_networks_encode_a_state_once_for_its_n_samples():
    """Repeating the features of each state n times equals encoding n copies of the state."""
    from common.bcq_networks import E2E_STATE_DIM, flat_observation

    torch.manual_seed(0)
    bcq = make_bcq(0, image_channels=[4, 4, 4, 4, 4], hidden=(16,))
    image = torch.randint(0, 256, (3, 2, 64, 128), dtype=torch.uint8)
    s = flat_observation(image, torch.rand(3, 1), torch.rand(3, 2) * 2 - 1)
    assert s.shape == (3, E2E_STATE_DIM)
    a = torch.rand(3 * 4, 2) * 2 - 1
    q = bcq.loss.qvalue_network
    assert torch.allclose(q(s, a, 4), q(s.repeat_interleave(4, 0), a), atol=1e-5)
    xi = bcq.loss.actor_network
    assert torch.allclose(xi(s, a, 4), xi(s.repeat_interleave(4, 0), a), atol=1e-5)
    assert bcq.loss.act(s).shape == (3, 2)
