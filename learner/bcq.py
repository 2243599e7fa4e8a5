"""BCQ (Fujimoto, Meger and Precup 2019, "Off-Policy Deep Reinforcement Learning without
Exploration", Algorithm 1) on a flat state: the offline learner of GVF-BCQ (paper appendix
"GVF-BCQ Training", after Algorithm 2 has learned the GVFs) and of E2E-BCQ (appendix
"End-to-end BCQ Baseline Training", on an image trunk's features).

Hand-written because torchrl 0.14 has no BCQ; it has the shape of torchrl's `TD3Loss`:
networks made functional with `convert_to_functional`, target copies of the perturbation
actor and the twin critics that `torchrl.objectives.SoftUpdate` moves (BCQ: tau = 0.005),
a TD(0) value estimator (`make_value_estimator`, gamma), `set_keys(observation=...)`.

Networks (`common.bcq_networks`): G_omega (VAE), the perturbation xi (Phi = 0.05) and the twin
critics. Losses:
- VAE: MSE(reconstruction, a) + 0.5 * KL(N(mean, std) || N(0, 1)).
- Actor: -Q1(s, a + xi(s, a)), a ~ G(s) (BCQ, Algorithm 1).
- Critics: target y = r + gamma * (1 - terminated) * max_j [lambda min(Q1', Q2') + (1 - lambda)
  max(Q1', Q2')](s', a_j), lambda = 0.75, over n = 10 actions a_j = a~_j + xi'(s', a~_j),
  a~_j ~ G(s') (soft clipped double Q-learning); loss MSE(Q1, y) + MSE(Q2, y).
- Acting: n = 10 actions a_j as above with the online networks, the argmax of Q1.

Each loss reaches only its own network (G is sampled without gradient for the actor and
the critic is detached there), so the three can be summed under one optimiser (lr 1e-4).
Networks are one hidden layer of 256 ReLU units with linear outputs, as the appendix says
(but xi's Phi * tanh, BCQ's bound); the decoder also reads s, as BCQ's state-conditioned
generative model requires. Actions live in LaneDrive's box [-1, 1]^2, where the paper clipped
to the Jackal's [-pi/2, pi/2] x [0.1, 0.6].
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.nn import dispatch
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.objectives import LossModule, SoftUpdate, ValueEstimators
from torchrl.objectives.utils import dispatch_value_estimator

from common.bcq_networks import HIDDEN, VAE, BCQPolicy, Perturbation, TwinQ, make_bcq_networks, select_action
from common.layers import ACTION_DIM


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
    def _sample_actions(self, s: Tensor, actor_params: TensorDictBase, n: int = 1) -> Tensor:
        """n actions a~ ~ G(s) per state, perturbed by xi with `actor_params` (online or target), (B * n, d_a)."""
        with self.vae_network_params.to_module(self.vae_network):
            a = self.vae_network.decode(s, n)
        with actor_params.to_module(self.actor_network):
            return self.actor_network(s, a, n)

    def vae_loss(self, s: Tensor, a: Tensor) -> tuple[Tensor, Tensor]:
        with self.vae_network_params.to_module(self.vae_network):
            recon, mean, std = self.vae_network(s, a)
        kl = -0.5 * (1 + torch.log(std.pow(2)) - mean.pow(2) - std.pow(2)).mean()
        return (recon - a).pow(2).mean(), kl

    def qvalue_loss(self, td: TensorDictBase) -> tuple[Tensor, Tensor, Tensor]:
        k = self.tensor_keys
        s, a, s_next = td.get(k.observation), td.get(k.action), td.get(("next", k.observation))
        with torch.no_grad():
            a_rep = self._sample_actions(s_next, self.target_actor_network_params, self.n_samples)
            with self.target_qvalue_network_params.to_module(self.qvalue_network):
                q = self.qvalue_network(s_next, a_rep, self.n_samples)
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
        with (
            self.vae_network_params.to_module(self.vae_network),
            self.actor_network_params.to_module(self.actor_network),
            self.qvalue_network_params.to_module(self.qvalue_network),
        ):
            a = select_action(self.vae_network, self.actor_network, self.qvalue_network, s, self.n_samples)
        return a.reshape(*state.shape[:-1], a.shape[-1])

    def policy(self) -> BCQPolicy:
        """The acting network with the online parameters (copies), for checkpoints and the evaluator."""
        nets = []
        for name in ("vae_network", "actor_network", "qvalue_network"):
            module = copy.deepcopy(getattr(self, name))
            getattr(self, f"{name}_params").detach().clone().to_module(module)
            nets.append(module)
        return BCQPolicy(*nets, n_samples=self.n_samples)


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
    image_channels=None,
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
    """BCQ with the paper's settings (appendix "GVF-BCQ Training") and BCQ's own where the paper is silent;
    with `image_channels`, E2E-BCQ on flat observations (`common.bcq_networks.flat_observation`)."""
    loss = BCQLoss(
        *make_bcq_networks(
            state_dim,
            image_channels=image_channels,
            action_dim=action_dim,
            hidden=hidden,
            latent_dim=latent_dim,
            Phi=Phi,
        ),
        lmbda=lmbda,
        n_samples=n_samples,
        kl_weight=kl_weight,
    )
    loss.make_value_estimator(ValueEstimators.TD0, gamma=discount)
    return BCQ(loss, torch.optim.Adam(loss.parameters(), lr=lr), SoftUpdate(loss, tau=tau))
