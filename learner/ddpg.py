"""DDPG (Lillicrap et al. 2016) on the predictive representation phi, or on images for the
baselines (paper section 3 and appendix, "GVF-DDPG Training", "Baseline DDPG Training").

torchrl's `DDPGLoss` computes both losses with target copies of the actor and the critic
(`delay_actor=True, delay_value=True`, as the paper uses target networks for both) and a
TD(0) target r + discount * (1 - terminated) * Q'(s', pi'(s')); the actor loss is
-Q(s, pi(s)) with the critic's parameters detached. `SoftUpdate` moves the targets by
`target_update` (paper: 0.001) after each optimiser step. Learning rates default to the
paper's 1e-6 (actor) and 1e-4 (critic); minibatches are drawn uniformly by the caller.

For GVF-DDPG the actor and critic read `phi` (computed by the caller from the GVF network
without gradient); for the image baselines they read the observation keys directly.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import Tensor, nn
from torchrl.objectives import DDPGLoss, SoftUpdate, ValueEstimators


class DDPG:
    """DDPG losses, optimisers and target updates for one actor/critic pair."""

    def __init__(self, actor: nn.Module, critic: nn.Module, *,
                 actor_in_keys: Sequence[str], critic_in_keys: Sequence[str],
                 discount: float = 0.99, target_update: float = 0.001,
                 lr_actor: float = 1e-6, lr_critic: float = 1e-4):
        self.actor, self.critic = actor, critic
        self.loss_module = DDPGLoss(
            TensorDictModule(actor, in_keys=list(actor_in_keys), out_keys=["action"]),
            TensorDictModule(critic, in_keys=list(critic_in_keys),
                             out_keys=["state_action_value"]),
            delay_actor=True, delay_value=True, loss_function="l2")
        self.loss_module.make_value_estimator(ValueEstimators.TD0, gamma=discount)
        self.target_updater = SoftUpdate(self.loss_module, tau=target_update)
        # fused: one kernel per step instead of one per tensor
        self.actor_optimizer = torch.optim.Adam(actor.parameters(), lr=lr_actor, fused=True)
        self.critic_optimizer = torch.optim.Adam(critic.parameters(), lr=lr_critic, fused=True)

    def loss(self, batch: TensorDictBase) -> tuple[Tensor, TensorDictBase]:
        """loss_actor + loss_value on a uniform minibatch (their gradients are disjoint)."""
        out = self.loss_module(batch)
        return out["loss_actor"] + out["loss_value"], out

    def zero_grad(self) -> None:
        self.actor_optimizer.zero_grad(set_to_none=True)
        self.critic_optimizer.zero_grad(set_to_none=True)

    def step(self) -> None:
        """Apply the gradients, then move the target networks (Lillicrap et al., Algorithm 1)."""
        self.critic_optimizer.step()
        self.actor_optimizer.step()
        self.target_updater.step()

    def update(self, batch: TensorDictBase) -> TensorDictBase:
        """One full DDPG update on `batch`; returns torchrl's loss TensorDict."""
        self.zero_grad()
        total, out = self.loss(batch)
        total.backward()
        self.step()
        return out.detach()

    def state_dict(self) -> dict:
        return {"loss": self.loss_module.state_dict(),
                "actor_optimizer": self.actor_optimizer.state_dict(),
                "critic_optimizer": self.critic_optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.loss_module.load_state_dict(state["loss"])
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self.critic_optimizer.load_state_dict(state["critic_optimizer"])
