"""DDPG (learner/ddpg.py) with the paper's branched actor and critic: target updates are
exact, and it learns continuous tasks (a contextual bandit fast, Pendulum-v1 slow)."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict import TensorDict

from common.critics import BranchedCritic
from common.networks import BranchedActor
from learner.ddpg import DDPG
from learner.metrics import steering_diagnostics


def make(obs_dim: int, n_actions: int, **kwargs) -> DDPG:
    actor = BranchedActor(obs_dim, [64, 64], n_actions=n_actions)
    critic = BranchedCritic(obs_dim, [64, 64], n_actions=n_actions)
    return DDPG(actor, critic, actor_in_keys=["phi"], critic_in_keys=["phi", "action"], **kwargs)


def random_batch(n: int) -> TensorDict:
    """n transitions with a 3-dim phi, random actions in [-1, 1], none terminal."""
    return TensorDict(
        {
            "phi": torch.randn(n, 3),
            "action": torch.rand(n, 2) * 2 - 1,
            "next": {
                "phi": torch.randn(n, 3),
                "reward": torch.randn(n, 1),
                "done": torch.zeros(n, 1, dtype=torch.bool),
                "terminated": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        [n],
    )


def test_soft_update_moves_targets_by_tau_and_losses_touch_their_own_networks():
    torch.manual_seed(0)
    ddpg = make(3, 2, target_update=0.001, lr_actor=1e-2, lr_critic=1e-2)
    params = ddpg.loss_module
    before = {k: v.clone() for k, v in params.target_actor_network_params.items(True, True)}
    batch = random_batch(16)
    ddpg.zero_grad()
    _, out = ddpg.loss(batch)
    out["loss_actor"].backward()
    assert all(p.grad is None for p in ddpg.critic.parameters())  # critic detached in actor loss
    ddpg.update(batch)
    for key, old in before.items():
        online = params.actor_network_params.get(key)
        target = params.target_actor_network_params.get(key)
        assert torch.allclose(target, old + 0.001 * (online - old), atol=1e-7)


def test_the_speed_hold_keeps_the_speed_branch_for_its_updates_then_lets_it_learn():
    torch.manual_seed(0)
    ddpg = make(3, 2, lr_actor=1e-2, lr_critic=1e-2, speed_hold=3)
    steer, speed = (list(ddpg.actor.branches[i].parameters()) for i in (0, 1))
    steer0, speed0 = [p.clone() for p in steer], [p.clone() for p in speed]
    batch = random_batch(16)
    for _ in range(3):
        ddpg.update(batch)
    assert all(torch.equal(a, b) for a, b in zip(speed0, speed))
    assert not all(torch.equal(a, b) for a, b in zip(steer0, steer))
    ddpg.update(batch)  # the 4th update steps the speed branch too
    assert not all(torch.equal(a, b) for a, b in zip(speed0, speed))
    with pytest.raises(ValueError, match="speed_hold must be >= 0"):
        make(3, 2, speed_hold=-1)
    with pytest.raises(ValueError, match="needs a branched actor"):
        DDPG(torch.nn.Linear(3, 2), ddpg.critic, actor_in_keys=["phi"], critic_in_keys=["phi", "action"], speed_hold=1)


def test_actor_step_size_decays_linearly_then_holds_and_resumes_where_it_was():
    torch.manual_seed(0)
    ddpg = make(3, 2, lr_actor=1e-3, lr_critic=1e-2, lr_actor_decay_updates=4, lr_actor_final=0.25)
    batch = random_batch(8)
    seen = []
    for _ in range(6):
        seen.append(ddpg.actor_optimizer.param_groups[0]["lr"])
        ddpg.update(batch)
    assert seen == pytest.approx([1e-3, 0.8125e-3, 0.625e-3, 0.4375e-3, 0.25e-3, 0.25e-3])
    assert ddpg.critic_optimizer.param_groups[0]["lr"] == 1e-2
    state = ddpg.state_dict()
    fresh = make(3, 2, lr_actor=1e-3, lr_critic=1e-2, lr_actor_decay_updates=4, lr_actor_final=0.25)
    fresh.load_state_dict(state)
    fresh.update(batch)
    assert fresh.actor_optimizer.param_groups[0]["lr"] == pytest.approx(0.25e-3)


def test_actor_step_size_holds_then_decays_and_resumes_where_it_was():
    torch.manual_seed(0)
    kwargs = dict(lr_actor=1e-3, lr_critic=1e-2, lr_actor_decay_updates=2, lr_actor_final=0.5, lr_actor_decay_after=3)
    ddpg = make(3, 2, **kwargs)
    batch = random_batch(8)
    seen = []
    for _ in range(5):
        seen.append(ddpg.actor_optimizer.param_groups[0]["lr"])
        ddpg.update(batch)
    # held for 3 updates, then 2 to fall to half
    assert seen == pytest.approx([1e-3, 1e-3, 1e-3, 1e-3, 0.75e-3])
    fresh = make(3, 2, **kwargs)
    fresh.load_state_dict(ddpg.state_dict())
    for _ in range(3):
        fresh.update(batch)
        assert fresh.actor_optimizer.param_groups[0]["lr"] == pytest.approx(0.5e-3)


def test_ddpg_solves_a_contextual_bandit():
    """One-step episodes, r = -(a0 - 0.5 s0)^2 - (a1 + 0.3 s1)^2: pi*(s) = (0.5 s0, -0.3 s1).

    Tolerance: mean |pi(s) - pi*(s)| < 0.08 on fresh states (initially ~0.2).
    """
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    ddpg = make(3, 2, lr_actor=1e-3, lr_critic=3e-3, target_update=0.01)

    def optimum(s):
        return torch.stack([0.5 * s[:, 0], -0.3 * s[:, 1]], -1)

    for _ in range(800):
        s = torch.rand(128, 3, generator=g) * 2 - 1
        a = torch.rand(128, 2, generator=g) * 2 - 1  # uniform behaviour: off-policy
        r = -((a - optimum(s)) ** 2).sum(-1, keepdim=True)
        ddpg.update(
            TensorDict(
                {
                    "phi": s,
                    "action": a,
                    "next": {
                        "phi": s,
                        "reward": r,
                        "done": torch.ones(128, 1, dtype=torch.bool),
                        "terminated": torch.ones(128, 1, dtype=torch.bool),
                    },
                },
                [128],
            )
        )
    s = torch.rand(2000, 3, generator=g) * 2 - 1
    with torch.no_grad():
        error = (ddpg.actor(s) - optimum(s)).abs().mean()
    print(f"bandit mean |pi - pi*| {error:.4f}")
    assert error < 0.08, error


@pytest.mark.slow
def test_ddpg_learns_pendulum_from_low_dim_state():
    """Pendulum-v1 (torque = 2 * action): mean return of 5 greedy episodes > -400 after
    15k steps (random policy ~ -1200, solved ~ -150)."""
    from actors.exploration import OrnsteinUhlenbeck
    from learner.replay import ImportanceResamplingReplay

    torch.manual_seed(0)
    torch.set_num_threads(1)
    env = gym.make("Pendulum-v1")
    ddpg = make(3, 1, lr_actor=1e-3, lr_critic=1e-3, target_update=0.005, discount=0.99)
    replay = ImportanceResamplingReplay(50_000, seed=0)
    noise = OrnsteinUhlenbeck(1, 1, theta=0.15, sigma=0.3, dt=1.0, seed=0)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for step in range(15_000):
        with torch.no_grad():
            action = ddpg.actor(torch.as_tensor(obs)[None]).numpy()[0]
        if step < 1000:
            action = rng.uniform(-1, 1, 1).astype(np.float32)
        action = np.clip(action + noise.sample()[0], -1, 1)
        next_obs, reward, terminated, truncated, _ = env.step(2.0 * action)
        replay.extend(
            TensorDict(
                {
                    "phi": torch.as_tensor(obs)[None],
                    "action": torch.as_tensor(action)[None],
                    "next_phi": torch.as_tensor(next_obs)[None],
                    "reward": torch.tensor([[reward / 10.0]], dtype=torch.float32),
                    "terminated": torch.tensor([[terminated]]),
                    "rho": torch.ones(1, 1),
                },
                [1],
            )
        )
        obs = next_obs
        if terminated or truncated:
            obs, _ = env.reset()
            noise.reset()
        if step >= 1000:
            b = replay.sample_uniform(128)
            ddpg.update(
                TensorDict(
                    {
                        "phi": b["phi"],
                        "action": b["action"],
                        "next": {
                            "phi": b["next_phi"],
                            "reward": b["reward"],
                            "done": b["terminated"],
                            "terminated": b["terminated"],
                        },
                    },
                    [128],
                )
            )
    returns = []
    for episode in range(5):
        obs, _ = env.reset(seed=100 + episode)
        total, done = 0.0, False
        while not done:
            with torch.no_grad():
                action = ddpg.actor(torch.as_tensor(obs)[None]).numpy()[0]
            obs, reward, terminated, truncated, _ = env.step(2.0 * action)
            total += reward
            done = terminated or truncated
        returns.append(total)
    print(f"Pendulum greedy returns {np.round(returns)}")
    assert np.mean(returns) > -400


class LinearQ(torch.nn.Module):
    """Q(phi, a) = w * a0: a critic whose preferred first action is +1 (w > 0) or -1 (w < 0)."""

    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.ones(1))

    def forward(self, phi, action):
        return self.w * action[..., :1]


@pytest.mark.parametrize("min_q, expected", [(False, 1.0), (True, 0.0)])
def test_the_pessimistic_actor_follows_the_smaller_of_two_disagreeing_critics(min_q, expected):
    """Critics Q1 = a0 and Q2 = -a0, held fixed: TD3's actor (Q1) drives a0 to +1; with
    actor_min_q it maximises min(a0, -a0) = -|a0|, whose best is a0 = 0."""
    torch.manual_seed(0)
    actor = BranchedActor(3, [32], n_actions=2, squash="tanh")
    ddpg = DDPG(
        actor, LinearQ(), actor_in_keys=["phi"], critic_in_keys=["phi", "action"],
        td3=True, actor_delay=1, lr_actor=1e-2, lr_critic=0.0, actor_min_q=min_q,
    )  # fmt: skip
    ddpg.loss_module.qvalue_network_params["module", "w"].data.copy_(torch.tensor([[1.0], [-1.0]]))
    batch = random_batch(64)
    for _ in range(300):
        ddpg.update(batch)
    with torch.no_grad():
        a0 = actor(torch.randn(256, 3))[:, 0]
    assert a0.mean().item() == pytest.approx(expected, abs=0.1)
    assert ddpg.loss_module.qvalue_network_params["module", "w"].flatten().tolist() == [1.0, -1.0]  # critics held


class AffineQ(torch.nn.Module):
    """Q(phi, a) = w . a + phi0: dQ/da is w wherever the critic is read."""

    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.tensor([0.5, -2.0]))

    def forward(self, phi, action):
        return (action * self.w).sum(-1, keepdim=True) + phi[..., :1]


@pytest.mark.parametrize("td3", [False, True])
def test_the_action_gradient_is_the_critics_at_the_actors_action_and_changes_nothing(td3):
    torch.manual_seed(0)
    actor = BranchedActor(3, [16], n_actions=2, squash="tanh")
    ddpg = DDPG(actor, AffineQ(), actor_in_keys=["phi"], critic_in_keys=["phi", "action"], td3=td3)
    if td3:  # the twins: TD3's actor climbs the first, so the second's gradient must not show
        ddpg.loss_module.qvalue_network_params["module", "w"].data.copy_(torch.tensor([[0.5, -2.0], [3.0, 3.0]]))
    batch = random_batch(8)
    stored = batch["action"].clone()
    action, grad = ddpg.action_gradient(batch)
    with torch.no_grad():
        assert torch.equal(action, actor(batch["phi"]))
    assert torch.allclose(grad, torch.tensor([0.5, -2.0]).expand(8, 2))
    assert all(p.grad is None for p in actor.parameters())
    assert torch.equal(batch["action"], stored) and not batch["action"].requires_grad  # the batch untouched


def test_actor_min_q_without_twin_critics_is_refused():
    with pytest.raises(ValueError, match="actor_min_q"):
        make(3, 2, actor_min_q=True)


def test_steering_diagnostics_sign_towards_the_centre_on_hand_made_states():
    """alpha > 0 is left of the centre, so steering right (negative) goes back: at alpha = +0.5 a
    gradient of -1 points to the centre, at alpha = -0.4 one of +2 does, at -0.6 one of -1 does not."""
    alpha = torch.tensor([[0.5], [-0.4], [-0.6], [0.1]])
    action = torch.tensor([[-0.2, 0.0], [0.3, 0.0], [-0.1, 0.0], [0.9, 0.0]])
    dq_da = torch.tensor([[-1.0, 4.0], [2.0, -4.0], [-1.0, 0.0], [5.0, 0.0]])
    out = {k: float(v) for k, v in steering_diagnostics(action, dq_da, alpha).items()}
    assert out["diag/off_centre_share"] == pytest.approx(0.75)
    assert out["diag/critic_to_centre"] == pytest.approx(2 / 3)
    assert out["diag/dq_dsteer_to_centre"] == pytest.approx((1.0 + 2.0 - 1.0) / 3)
    assert out["diag/steer_to_centre"] == pytest.approx((0.2 + 0.3 - 0.1) / 3)
    assert out["diag/dq_dsteer_abs"] == pytest.approx(9 / 4) and out["diag/dq_dspeed_abs"] == pytest.approx(2.0)
    centred = steering_diagnostics(action, dq_da, torch.zeros(4, 1))
    assert "diag/critic_to_centre" not in centred and float(centred["diag/off_centre_share"]) == 0.0
