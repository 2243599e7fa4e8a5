"""BCQ (Fujimoto, Meger and Precup 2019, "Off-Policy Deep Reinforcement Learning without
Exploration", Algorithm 1) on a flat state: the offline learner of GVF-BCQ (paper appendix
"GVF-BCQ Training", after Algorithm 2 has learned the GVFs) and of E2E-BCQ (appendix
"End-to-end BCQ Baseline Training", on an image trunk's features).

Hand-written because torchrl 0.14 has no BCQ; it has the shape of torchrl's `TD3Loss`:
networks made functional with `convert_to_functional`, target copies of the perturbation
actor and the twin critics that `torchrl.objectives.SoftUpdate` moves (BCQ: tau = 0.005),
a TD(0) value estimator (`make_value_estimator`, gamma), `set_keys(observation=...)`.

- `VAE` G_omega(a|s): (s, a) -> 256 -> mean, log std of z (d_z = 4); (s, z) -> 256 -> a.
  Loss = MSE(reconstruction, a) + 0.5 * KL(N(mean, std) || N(0, 1)). Sampling draws
  z ~ N(0, 1) clipped to [-0.5, 0.5] (BCQ), the action clipped to the box.
- `Perturbation` xi_phi(s, a, Phi): (s, a) -> 256 -> Phi * tanh(.), Phi = 0.05; the action
  a + xi is clipped to [-1, 1]^2. Loss = -Q1(s, a + xi(s, a)), a ~ G(s) (BCQ, Algorithm 1).
- `TwinQ` Q1, Q2: (s, a) -> 256 -> 1 each. Target y = r + gamma * (1 - terminated) * max_j
  [lambda min(Q1', Q2') + (1 - lambda) max(Q1', Q2')](s', a_j), lambda = 0.75, over n = 10
  actions a_j = a~_j + xi'(s', a~_j), a~_j ~ G(s') (soft clipped double Q-learning).
  Loss = MSE(Q1, y) + MSE(Q2, y).
- Acting: n = 10 actions a_j as above with the online networks, the argmax of Q1.

Each loss reaches only its own network (G is sampled without gradient for the actor and
the critic is detached there), so the three can be summed under one optimiser (lr 1e-4).
Networks are one hidden layer of 256 ReLU units with linear outputs, as the appendix says
(but xi's Phi * tanh, BCQ's bound); the decoder also reads s, as BCQ's state-conditioned
generative model requires. Actions live in LaneDrive's box [-1, 1]^2, where the paper clipped
to the Jackal's [-pi/2, pi/2] x [0.1, 0.6].
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.nn import dispatch
from tensordict.utils import NestedKey
from torch import Tensor, nn
from torchrl.objectives import LossModule, SoftUpdate, ValueEstimators
from torchrl.objectives.utils import dispatch_value_estimator

from common.networks import ACTION_DIM, mlp

HIDDEN = (256,)


class VAE(nn.Module):
    """State-conditioned generative model of the data's actions, G_omega(a|s)."""

    def __init__(self, state_dim: int, action_dim: int = ACTION_DIM, latent_dim: int = 4, hidden=HIDDEN):
        super().__init__()
        self.latent_dim = latent_dim
        self.encoder = mlp(state_dim + action_dim, hidden, 2 * latent_dim)  # mean, log std
        self.decoder = mlp(state_dim + latent_dim, hidden, action_dim)

    def forward(self, s: Tensor, a: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Reconstruction (unclipped, so the loss keeps its gradient at the box edge), mean, std."""
        mean, log_std = self.encoder(torch.cat([s, a], -1)).chunk(2, -1)
        std = log_std.clamp(-4.0, 15.0).exp()  # BCQ's clamp, for numerical stability
        z = mean + std * torch.randn_like(std)
        return self.decoder(torch.cat([s, z], -1)), mean, std

    def decode(self, s: Tensor) -> Tensor:
        """Sample a ~ G(s): z ~ N(0, 1) clipped to [-0.5, 0.5] keeps samples near the data's modes."""
        z = torch.randn(*s.shape[:-1], self.latent_dim, device=s.device, dtype=s.dtype).clamp(-0.5, 0.5)
        return self.decoder(torch.cat([s, z], -1)).clamp(-1.0, 1.0)


class Perturbation(nn.Module):
    """xi_phi(s, a, Phi): moves a generated action by at most Phi (BCQ's Phi, not the representation phi)."""

    def __init__(self, state_dim: int, action_dim: int = ACTION_DIM, Phi: float = 0.05, hidden=HIDDEN):
        super().__init__()
        self.Phi = Phi
        self.net = mlp(state_dim + action_dim, hidden, action_dim)

    def forward(self, s: Tensor, a: Tensor) -> Tensor:
        xi = self.Phi * torch.tanh(self.net(torch.cat([s, a], -1)))
        return (a + xi).clamp(-1.0, 1.0)


class TwinQ(nn.Module):
    """Two independent critics; forward gives (..., 2) = [Q1, Q2]."""

    def __init__(self, state_dim: int, action_dim: int = ACTION_DIM, hidden=HIDDEN):
        super().__init__()
        self.q1_net = mlp(state_dim + action_dim, hidden, 1)
        self.q2_net = mlp(state_dim + action_dim, hidden, 1)

    def forward(self, s: Tensor, a: Tensor) -> Tensor:
        x = torch.cat([s, a], -1)
        return torch.cat([self.q1_net(x), self.q2_net(x)], -1)

    def q1(self, s: Tensor, a: Tensor) -> Tensor:
        return self.q1_net(torch.cat([s, a], -1)).squeeze(-1)


class BCQLoss(LossModule):
    """BCQ's three losses on a batch (B,) of transitions in torchrl's layout:
    observation, action, ("next", observation | reward | done | terminated), rewards (B, 1)."""

    @dataclass
    class _AcceptedKeys:
        observation: NestedKey = "observation"
        action: NestedKey = "action"
        reward: NestedKey = "reward"
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"

    tensor_keys: _AcceptedKeys
    default_keys = _AcceptedKeys
    default_value_estimator = ValueEstimators.TD0
    out_keys = ["loss_vae", "loss_qvalue", "loss_actor", "loss_recon", "loss_kl", "pred_value", "target_value"]

    vae_network: VAE
    vae_network_params: TensorDictParams
    target_vae_network_params: TensorDictParams
    actor_network: Perturbation
    actor_network_params: TensorDictParams
    target_actor_network_params: TensorDictParams
    qvalue_network: TwinQ
    qvalue_network_params: TensorDictParams
    target_qvalue_network_params: TensorDictParams

    def __init__(
        self,
        vae: VAE,
        actor: Perturbation,
        qvalue: TwinQ,
        *,
        lmbda: float = 0.75,
        n_samples: int = 10,
        kl_weight: float = 0.5,
    ) -> None:
        super().__init__()
        self._in_keys = None
        self.lmbda, self.n_samples, self.kl_weight = lmbda, n_samples, kl_weight
        self.convert_to_functional(vae, "vae_network", create_target_params=False)
        self.convert_to_functional(actor, "actor_network", create_target_params=True)
        self.convert_to_functional(qvalue, "qvalue_network", create_target_params=True)

    # -- torchrl plumbing: keys and the TD(0) target ----------------------------------------
    def _set_in_keys(self) -> None:
        k = self.tensor_keys
        self._in_keys = [
            k.observation,
            k.action,
            *[("next", key) for key in (k.observation, k.reward, k.done, k.terminated)],
        ]

    @property
    def in_keys(self):
        if self._in_keys is None:
            self._set_in_keys()
        return self._in_keys

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        if self._value_estimator is not None:
            k = self.tensor_keys
            self._value_estimator.set_keys(reward=k.reward, done=k.done, terminated=k.terminated)
        self._set_in_keys()

    def make_value_estimator(self, value_type: ValueEstimators = None, **hyperparams):
        """TD(0) only: BCQ bootstraps from one next state; `gamma` is the discount."""
        value_type, hp = self._prepare_value_estimator_kwargs(value_type, **hyperparams)
        if value_type is None:
            return self
        k = self.tensor_keys
        keys = {"reward": k.reward, "done": k.done, "terminated": k.terminated}
        dispatch_value_estimator(
            self, value_type, supported=(ValueEstimators.TD0,), tensor_keys=keys, value_network=None, **hp
        )
        return self

    # -- the maths ---------------------------------------------------------------------------
    def _sample_actions(self, s: Tensor, actor_params: TensorDictBase) -> Tensor:
        """a~ ~ G(s), perturbed by xi with `actor_params` (online or target)."""
        with self.vae_network_params.to_module(self.vae_network):
            a = self.vae_network.decode(s)
        with actor_params.to_module(self.actor_network):
            return self.actor_network(s, a)

    def vae_loss(self, s: Tensor, a: Tensor) -> tuple[Tensor, Tensor]:
        with self.vae_network_params.to_module(self.vae_network):
            recon, mean, std = self.vae_network(s, a)
        kl = -0.5 * (1 + torch.log(std.pow(2)) - mean.pow(2) - std.pow(2)).mean()
        return (recon - a).pow(2).mean(), kl

    def qvalue_loss(self, td: TensorDictBase) -> tuple[Tensor, Tensor, Tensor]:
        k = self.tensor_keys
        s, a, s_next = td.get(k.observation), td.get(k.action), td.get(("next", k.observation))
        with torch.no_grad():
            s_rep = s_next.repeat_interleave(self.n_samples, 0)
            a_rep = self._sample_actions(s_rep, self.target_actor_network_params)
            with self.target_qvalue_network_params.to_module(self.qvalue_network):
                q = self.qvalue_network(s_rep, a_rep)
            q = self.lmbda * q.min(-1).values + (1 - self.lmbda) * q.max(-1).values  # soft clipped double Q
            v_next = q.view(-1, self.n_samples).max(-1).values.unsqueeze(-1)  # best of the n in-support actions
            target = self.value_estimator.value_estimate(td, next_value=v_next)
        with self.qvalue_network_params.to_module(self.qvalue_network):
            pred = self.qvalue_network(s, a)
        return (pred - target).pow(2).mean(0).sum(), pred.detach(), target.squeeze(-1)

    def actor_loss(self, s: Tensor) -> Tensor:
        with torch.no_grad():  # the actor learns a perturbation; G is trained by its own loss
            with self.vae_network_params.to_module(self.vae_network):
                a = self.vae_network.decode(s)
        with self.actor_network_params.to_module(self.actor_network):
            a = self.actor_network(s, a)
        with self.qvalue_network_params.detach().to_module(self.qvalue_network):
            return -self.qvalue_network.q1(s, a).mean()

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        k = self.tensor_keys
        s, a = tensordict.get(k.observation), tensordict.get(k.action)
        loss_recon, loss_kl = self.vae_loss(s, a)
        loss_qvalue, pred, target = self.qvalue_loss(tensordict)
        return TensorDict(
            loss_vae=loss_recon + self.kl_weight * loss_kl,
            loss_qvalue=loss_qvalue,
            loss_actor=self.actor_loss(s),
            loss_recon=loss_recon.detach(),
            loss_kl=loss_kl.detach(),
            pred_value=pred.mean(),
            target_value=target.mean(),
        )

    @torch.no_grad()
    def act(self, state: Tensor) -> Tensor:
        """BCQ's action for a state (d_s,) or a batch (B, d_s): the argmax of Q1 over n perturbed samples of G."""
        s = state.reshape(-1, state.shape[-1])
        s_rep = s.repeat_interleave(self.n_samples, 0)
        a = self._sample_actions(s_rep, self.actor_network_params)
        with self.qvalue_network_params.to_module(self.qvalue_network):
            best = self.qvalue_network.q1(s_rep, a).view(-1, self.n_samples).argmax(-1)
        a = a.view(len(s), self.n_samples, -1)[torch.arange(len(s)), best]
        return a.reshape(*state.shape[:-1], a.shape[-1])


@dataclass
class BCQ:
    """A BCQ learner: the loss, one Adam over its three networks and the target updater."""

    loss: BCQLoss
    optimizer: torch.optim.Optimizer
    target_updater: SoftUpdate

    def update(self, batch: TensorDictBase) -> TensorDictBase:
        """One step of BCQ's Algorithm 1 (lines 5-13) on a minibatch; returns the losses."""
        out = self.loss(batch)
        self.optimizer.zero_grad(set_to_none=True)
        (out["loss_vae"] + out["loss_qvalue"] + out["loss_actor"]).backward()
        self.optimizer.step()
        self.target_updater.step()
        return out.detach()


def make_bcq(
    state_dim: int,
    *,
    action_dim: int = ACTION_DIM,
    hidden=HIDDEN,
    latent_dim: int = 4,
    Phi: float = 0.05,
    lmbda: float = 0.75,
    n_samples: int = 10,
    kl_weight: float = 0.5,
    discount: float = 0.99,
    tau: float = 0.005,
    lr: float = 1e-4,
) -> BCQ:
    """BCQ with the paper's settings (appendix "GVF-BCQ Training") and BCQ's own where the paper is silent."""
    loss = BCQLoss(
        VAE(state_dim, action_dim, latent_dim, hidden),
        Perturbation(state_dim, action_dim, Phi, hidden),
        TwinQ(state_dim, action_dim, hidden),
        lmbda=lmbda,
        n_samples=n_samples,
        kl_weight=kl_weight,
    )
    loss.make_value_estimator(ValueEstimators.TD0, gamma=discount)
    return BCQ(loss, torch.optim.Adam(loss.parameters(), lr=lr), SoftUpdate(loss, tau=tau))
