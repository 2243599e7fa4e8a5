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

`td3=True` (an option, off by default: not the paper's algorithm) swaps in torchrl's `TD3Loss`
(Fujimoto et al. 2018): twin critics (a second copy of the critic, freshly initialised) with the
smaller target value, target-policy smoothing (clipped Gaussian noise on the target action), and
the actor stepped only every `actor_delay` updates.

`actor_min_q` (an option with td3, off by default) makes the actor maximise the smaller of the
twin critics' values, as SAC does, instead of TD3's first critic: where the two disagree (off the
data, e.g. at target speeds the replay has no crash for) the actor is not pulled towards the more
optimistic one.

`actor_on_crash_memory=False` (an option, on by default: the actor climbs Q on every item) leaves
the crash memory's items (`learner.replay.FROM_CRASHES`) out of the actor's loss: the critic
learns the crashes' cost from them, while the actor improves at the states its policy reaches,
not at copies of old pre-crash states whose steep Q gradients would steer every state.

`target_min_weight` (an option with td3, 1 by default: TD3's minimum) bootstraps from a blend of the
twin target critics, `learner.td3_target`.

`steer_slope_penalty` (an option, 0 by default) adds lambda E[(dQ/d steering)^2] at the minibatch's
actions to each critic's loss: measured, the critics' steering slope at off-centre states was ~10x
the true one and pointed to the centre at chance (docs/results.md, the steering probe); a slope the
data do not support then costs. `steer_slope_penalty_after` starts it after that many updates.
Written here: torchrl's losses have no action-gradient penalty.

`speed_hold` (an option, 0 by default) leaves the actor's speed branch unstepped for that many
updates, so the first drives keep the initial target speed while the steering learns (the speed had
risen to 13-14 m/s by 1,500 updates in every run, above the ~12 m/s of the 18 m bends). Measured
(docs/results.md lever SH): held at 11 m/s a run lapped all 12 at 1,000 updates, and once released
its speed crept as before.

`lr_actor_decay_updates` (an option, 0 by default) lowers the actor's step size linearly to
`lr_actor_final` of it over that many updates, so that a policy found early moves less later;
`lr_actor_decay_after` holds it for that many updates first (torch's `SequentialLR`), so that the
first laps are learned at the full step size.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import Tensor, nn
from torchrl.objectives import DDPGLoss, SoftUpdate, ValueEstimators

from learner.replay import FROM_CRASHES
from learner.td3_target import BlendedTD3Loss


def actor_schedule(optimizer: torch.optim.Optimizer, decay_updates: int, final: float, after: int):
    """Stepped once per update: the step size holds for `after` updates, falls linearly to `final`
    of it over `decay_updates`, then holds there; None where `decay_updates` is 0 (constant)."""
    if not decay_updates:
        return None
    decay = torch.optim.lr_scheduler.LinearLR(optimizer, 1.0, final, total_iters=decay_updates)
    if not after:
        return decay
    hold = torch.optim.lr_scheduler.ConstantLR(optimizer, factor=1.0, total_iters=after)
    return torch.optim.lr_scheduler.SequentialLR(optimizer, [hold, decay], milestones=[after])


class DDPG:
    """DDPG losses, optimisers and target updates for one actor/critic pair."""

    def __init__(
        self,
        actor: nn.Module,
        critic: nn.Module,
        *,
        actor_in_keys: Sequence[str],
        critic_in_keys: Sequence[str],
        discount: float = 0.99,
        target_update: float = 0.001,
        lr_actor: float = 1e-6,
        lr_critic: float = 1e-4,
        td3: bool = False,
        policy_noise: float = 0.2,
        noise_clip: float = 0.5,
        actor_delay: int = 2,
        lr_actor_decay_updates: int = 0,
        lr_actor_final: float = 0.1,
        lr_actor_decay_after: int = 0,
        actor_min_q: bool = False,
        actor_on_crash_memory: bool = True,
        target_min_weight: float = 1.0,
        steer_slope_penalty: float = 0.0,
        steer_slope_penalty_after: int = 0,
        speed_hold: int = 0,
    ):
        if actor_min_q and not td3:
            raise ValueError("actor_min_q needs td3 (twin critics)")
        self.actor, self.critic = actor, critic
        self.actor_min_q, self.actor_on_crash_memory = actor_min_q, actor_on_crash_memory
        if steer_slope_penalty < 0:
            raise ValueError(f"steer_slope_penalty must be >= 0, got {steer_slope_penalty}")
        self.steer_slope_penalty, self.steer_slope_penalty_after = steer_slope_penalty, steer_slope_penalty_after
        self.td3, self.actor_delay, self.steps = td3, actor_delay, 0
        # the speed branch of the actor's BranchedActor (DDPG-Image's sits under its trunk)
        speed = next((m.branches[1] for m in actor.modules() if hasattr(m, "branches") and len(m.branches) > 1), None)
        if speed_hold < 0 or (speed_hold and speed is None):
            raise ValueError(f"speed_hold must be >= 0 and needs a branched actor, got {speed_hold}")
        self.speed_hold, self.speed_branch = speed_hold, speed
        actor_module = TensorDictModule(actor, in_keys=list(actor_in_keys), out_keys=["action"])
        self.actor_module = actor_module

        def q(net: nn.Module) -> TensorDictModule:
            return TensorDictModule(net, in_keys=list(critic_in_keys), out_keys=["state_action_value"])

        if td3:
            twin = copy.deepcopy(critic)
            for module in twin.modules():  # the twin starts elsewhere, or the two critics agree
                if hasattr(module, "reset_parameters"):
                    module.reset_parameters()
            self.loss_module = BlendedTD3Loss(
                actor_module,
                [q(critic), q(twin)],
                bounds=(-1.0, 1.0),
                num_qvalue_nets=2,
                policy_noise=policy_noise,
                noise_clip=noise_clip,
                loss_function="l2",
                deactivate_vmap=True,
            )  # vmap cannot run the channels_last conv trunk
            self.loss_module.min_weight = target_min_weight
            # the twin critics' parameters live stacked in the loss module, not in `critic`
            critic_params = list(self.loss_module.qvalue_network_params.values(True, True))
        else:
            self.loss_module = DDPGLoss(actor_module, q(critic), delay_actor=True, delay_value=True, loss_function="l2")
            critic_params = list(critic.parameters())
        self.loss_module.make_value_estimator(ValueEstimators.TD0, gamma=discount)
        self.target_updater = SoftUpdate(self.loss_module, tau=target_update)
        # fused: one kernel per step instead of one per tensor
        self.actor_optimizer = torch.optim.Adam(actor.parameters(), lr=lr_actor, fused=True)
        self.critic_optimizer = torch.optim.Adam(critic_params, lr=lr_critic, fused=True)
        self.actor_schedule = actor_schedule(
            self.actor_optimizer, lr_actor_decay_updates, lr_actor_final, lr_actor_decay_after
        )

    def loss(self, batch: TensorDictBase) -> tuple[Tensor, TensorDictBase]:
        """loss_actor + loss_value on a uniform minibatch (their gradients are disjoint)."""
        out = self.loss_module(batch)
        if self.td3:  # one naming for both losses' outputs
            out["loss_value"] = out["loss_qvalue"]
            out["pred_value"] = out["pred_value"].reshape(2, -1)[0]
        acted = self.actor_batch(batch)
        if self.actor_min_q:
            out["loss_actor"] = self.pessimistic_actor_loss(acted)
        elif acted is not batch:
            loss = self.loss_module.actor_loss if self.td3 else self.loss_module.loss_actor
            out["loss_actor"] = loss(acted)[0]
        if self.steer_slope_penalty and self.steps >= self.steer_slope_penalty_after:
            out["loss_steer_slope"] = self.steer_slope_penalty * self.steer_slope_sq(batch)
            out["loss_value"] = out["loss_value"] + out["loss_steer_slope"]
        return out["loss_actor"] + out["loss_value"], out

    def steer_slope_sq(self, batch: TensorDictBase) -> Tensor:
        """sum over the critics of mean (dQ/d steering)^2 at the minibatch's own actions, differentiable
        in the critics' parameters (double backward); the actor takes no part."""
        qnet, stacked = self.critics()
        td = batch.select(*qnet.in_keys).clone(False)
        action = td["action"].detach().requires_grad_(True)
        terms = []
        for params in stacked:
            with params.to_module(qnet):
                q = qnet(td.clone(False).set("action", action))["state_action_value"]
            (grad,) = torch.autograd.grad(q.sum(), action, create_graph=True)
            terms.append(grad[:, 0].pow(2).mean())  # action 0 is the steering
        return torch.stack(terms).sum()

    def critics(self) -> tuple[nn.Module, list[TensorDictBase]]:
        """The critic network and the parameters of each critic (the twins' two with td3, else one)."""
        if self.td3:
            return self.loss_module.qvalue_network, list(self.loss_module.qvalue_network_params.unbind(0))
        return self.loss_module.value_network, [self.loss_module.value_network_params]

    def actor_batch(self, batch: TensorDictBase) -> TensorDictBase:
        """The items the actor's loss averages over: all, or those not from the crash memory."""
        if self.actor_on_crash_memory or FROM_CRASHES not in batch.keys():
            return batch
        return batch[~batch[FROM_CRASHES]]

    def pessimistic_actor_loss(self, batch: TensorDictBase) -> Tensor:
        """-min(Q1, Q2)(s, pi(s)), the critics' parameters detached.

        Written here because torchrl's TD3Loss takes the first critic only (its actor_loss)."""
        acted = self.actor_module(batch.select(*self.actor_module.in_keys).clone(False))
        qnet, stacked = self.critics()
        values = []
        for params in stacked:
            with params.detach().to_module(qnet):
                values.append(qnet(acted.select(*qnet.in_keys).clone(False))["state_action_value"])
        return -torch.minimum(*values).mean()

    @torch.enable_grad()
    def action_gradient(self, batch: TensorDictBase) -> tuple[Tensor, Tensor]:
        """pi(s) on `batch` and dQ/da there: the direction the actor's next step moves each action
        (with td3 the first twin's, the one TD3's actor climbs). Nothing is stepped or accumulated."""
        with torch.no_grad():
            action = self.actor_module(batch.select(*self.actor_module.in_keys).clone(False))["action"]
        qnet, stacked = self.critics()
        params = stacked[0]
        td = batch.select(*(k for k in qnet.in_keys if k != "action")).clone(False)
        td["action"] = action.detach().requires_grad_(True)
        with params.detach().to_module(qnet):
            q = qnet(td)["state_action_value"]
        (grad,) = torch.autograd.grad(q.sum(), td["action"])
        return action, grad

    def actor_steps_now(self) -> bool:
        """Whether this update steps the actor (every update; with td3 every `actor_delay`)."""
        self.steps += 1
        return not self.td3 or self.steps % self.actor_delay == 0

    def zero_grad(self) -> None:
        self.actor_optimizer.zero_grad(set_to_none=True)
        self.critic_optimizer.zero_grad(set_to_none=True)

    def step(self) -> None:
        """Apply the gradients, then move the target networks (Lillicrap et al., Algorithm 1)."""
        self.critic_optimizer.step()
        if self.actor_steps_now():
            if self.steps <= self.speed_hold:  # the speed branch keeps its initial target speed
                for p in self.speed_branch.parameters():
                    p.grad = None
            self.actor_optimizer.step()
        if self.actor_schedule is not None:
            self.actor_schedule.step()
        self.target_updater.step()

    def update(self, batch: TensorDictBase) -> TensorDictBase:
        """One full DDPG update on `batch`; returns torchrl's loss TensorDict."""
        self.zero_grad()
        total, out = self.loss(batch)
        total.backward()
        self.step()
        return out.detach()

    def state_dict(self) -> dict:
        return {
            "loss": self.loss_module.state_dict(),
            "steps": self.steps,
            "actor_optimizer": self.actor_optimizer.state_dict(),
            "critic_optimizer": self.critic_optimizer.state_dict(),
            "actor_schedule": None if self.actor_schedule is None else self.actor_schedule.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.loss_module.load_state_dict(state["loss"])
        self.steps = state.get("steps", 0)
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self.critic_optimizer.load_state_dict(state["critic_optimizer"])
        if self.actor_schedule is not None and state.get("actor_schedule") is not None:
            self.actor_schedule.load_state_dict(state["actor_schedule"])
