"""One combined learner update of GVF-DDPG and its baselines (Algorithm 1, lines 8-17, then
DDPG on phi), free of any transport or process code.

`LearningCore.add` is lines 8-10: rho = tau / mu_hat (learner.insert_rho) with the current g, stored.
`LearningCore.update` is lines 11-17 plus DDPG:

  rho_bar <- mean rho in D                                          (line 11)
  A ~ D with probability rho_i / sum rho_j                         (line 12)
  U ~ D uniformly (and the crash memory, scale.crash_memory)        (line 15)
  GVF TD step on A, targets from v(s') without gradient             (lines 13-14)
  discriminator BCE step on U, half of its actions replaced by eta  (lines 16-17)
  DDPG step on U with phi = [v(s), speed, last action], detached    (section 3)

The v(.) evaluations without gradient (v(s') on A, clamped to +-max |c| by default
(`ReturnBound`), phi(s) and phi(s') on U) are the only network work beyond one forward/backward
per network; the losses touch disjoint parameters, so one backward serves them all.
`scale.n_step` > 1: DDPG's next state and reward on U are an n-step window's (learner.nstep).

rho is computed at insert with the g of that moment (Algorithm 1), which makes two kinds of
stale ratio: the warm-up's, inserted before any update trained g (rho ~55 where a fitted g
gives ~1, so that block held most of the GVF sampling mass until evicted), and every item's
as g moves on. Hence (`AgentConfig`): before the first update g alone takes
`behaviour_warmup_updates` steps on the warm-up data and then every stored rho is
recomputed (`refresh_all_rho`, batched, rho_bar exact), and again every `rho_refresh_every`
updates; `refresh_rho` (default off) also rewrites the rho of each GVF minibatch after it is drawn.

Variants (`AgentConfig.representation`): predictive (gvf_ddpg, _g0, _g095) trains all
three parts; image and lowdim (the DDPG baselines) train DDPG alone, rho = 1.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor

from common.config.agent import AgentConfig, ScaleConfig, step_sizes
from common.networks import make_networks
from common.wire import AVERAGE, BEHAVIOUR
from learner.behaviour import behaviour_loss
from learner.ddpg import DDPG
from learner.ddpg_batch import STEPS, ddpg_reward, observation_batch, phi_batch, with_nstep_next
from learner.gvf import ReturnBound, cumulants, expand_gammas, gvf_loss, td_target
from learner.insert_rho import RHO_SLICE, InsertRho
from learner.metrics import actor_diagnostics, ddpg_metrics, prediction_error, steering_diagnostics
from learner.mirror import mirror
from learner.nstep import nstep_columns
from learner.offset_steer import OffsetSteer
from learner.policy_average import PolicyAverage
from learner.replay import CrashMemory, ImportanceResamplingReplay, compact, expand, sample_uniform_with

OBS_KEYS = ("image", "speed", "last_action")


def _obs(td: TensorDictBase) -> tuple[Tensor, Tensor, Tensor]:
    return td["image"], td["speed"], td["last_action"]


class LearningCore:
    """Networks, optimisers and the shared replay of one agent variant; see the module docstring."""

    def __init__(
        self,
        agent: AgentConfig,
        scale: ScaleConfig,
        *,
        device: str = "cpu",
        seed: int = 0,
        buffer_size: int | None = None,
        warmup: int | None = None,
    ):
        torch.manual_seed(seed)  # the global generator initialises the networks
        self.agent, self.scale, self.device = agent, scale, torch.device(device)
        self.batch_size = scale.batch_size
        self.warmup = scale.warmup if warmup is None else warmup
        self.nets = make_networks(agent, scale)
        for module in self.nets.modules().values():
            module.to(self.device)
        self.predictive = self.nets.representation == "predictive"
        # the replay stays in host memory (torchrl's sum tree is CPU-only); batches move over
        self.replay = ImportanceResamplingReplay(scale.buffer_size if buffer_size is None else buffer_size, seed=seed)
        self.crashes = CrashMemory(scale.crash_memory) if scale.crash_memory else None
        self.generator = torch.Generator().manual_seed(seed)
        steps = step_sizes(agent, scale)
        self.discount = steps["discount"]
        if self.predictive:
            self.gammas = expand_gammas(agent.gammas, len(agent.cumulants)).to(self.device)
            self.gvf_optimizer = torch.optim.Adam(self.nets.gvf.parameters(), lr=steps["lr_gvf"], fused=True)
            behaviour = self.nets.behaviour.parameters()
            self.behaviour_optimizer = torch.optim.Adam(behaviour, lr=steps["lr_behaviour"], fused=True)
            keys = ["phi"]
        else:
            keys = list(OBS_KEYS)
        lowdim = ["lowdim"] if self.nets.representation == "lowdim" else []
        self.ddpg = DDPG(
            self.nets.actor,
            self.nets.critic,
            actor_in_keys=keys + lowdim,
            critic_in_keys=keys + ["action"] + lowdim,
            discount=steps["discount"],
            target_update=steps["target_update"],
            lr_actor=steps["lr_actor"],
            lr_critic=steps["lr_critic"],
            td3=scale.td3,
            policy_noise=scale.td3_policy_noise,
            noise_clip=scale.td3_noise_clip,
            actor_delay=scale.td3_actor_delay,
            lr_actor_decay_updates=scale.lr_actor_decay_updates,
            lr_actor_final=scale.lr_actor_final,
            lr_actor_decay_after=scale.lr_actor_decay_after,
            steer_slope_penalty=scale.critic_steer_penalty,
            steer_slope_penalty_after=scale.critic_steer_penalty_after,
            speed_hold=scale.actor_speed_hold,
            actor_min_q=scale.actor_min_q,
            actor_on_crash_memory=scale.crash_memory_actor,
            target_min_weight=scale.td3_target_min_weight,
        )
        self.updates = 0
        self.warm = False  # g trained on the warm-up data and every rho recomputed
        self.held_out: TensorDictBase | None = None
        self.insert_rho = InsertRho(agent, self.nets.behaviour) if self.predictive else None
        self.skipped_nonfinite = 0  # updates whose loss or a gradient was not finite: skipped
        self.average = PolicyAverage(self.nets.policy, scale.policy_average) if scale.policy_average else None
        bounded = self.predictive and agent.gvf_bootstrap_bound  # learner.gvf.ReturnBound
        self.bound = ReturnBound(len(agent.cumulants), self.device) if bounded else None
        self.offset_steer = OffsetSteer.build(self.nets, agent, scale)  # an option, off as in the paper

    # --- Algorithm 1, lines 8-10 -------------------------------------------------------
    def rho(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        """rho = tau(a|s) / mu_hat(a|s) under the current g, clipped; and which ones were clipped."""
        return self.insert_rho.by_g(td)

    @torch.no_grad()
    def refresh_all_rho(self, slice_size: int = 4 * RHO_SLICE) -> None:
        """Recompute the rho of every stored item with the current g; rho_bar becomes exact."""
        for index, stored in self.replay.slots(slice_size):
            obs = TensorDict(
                {
                    "image": stored["image"].view(torch.uint8),
                    "speed": stored["speed"],
                    "last_action": stored["last_action"],
                    "action": stored["action"],
                },
                batch_size=stored.batch_size,
            ).to(self.device)
            self.replay.update_rho(index, self.rho(obs)[0])
        self.replay.resum_rho()

    @property
    def needs_warm_start(self) -> bool:
        """The next update would first train g alone and refresh every rho (seconds of work)."""
        return self.predictive and not self.warm and self.agent.behaviour_warmup_updates > 0

    def warm_start(self) -> None:
        """g alone on the warm-up data, then every rho recomputed with it (module docstring)."""
        for _ in range(self.agent.behaviour_warmup_updates):
            uniform = self._uniform()
            loss = behaviour_loss(self.nets.behaviour, _obs(uniform), uniform["action"], self.generator)
            self.behaviour_optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.behaviour_optimizer.step()
        self.refresh_all_rho()
        self.warm = True

    def add(self, transitions: TensorDictBase) -> None:
        """Store a batch of transitions (torchrl convention, see learner.replay) with its rho. Items
        with a finite "log_mu" (the actors' log mu_hat, `learner.rho_at=actor`) take rho from it:
        only tau is computed here; the others run the discriminator."""
        transitions = transitions.to(self.device)
        if self.bound is not None:
            self.bound.update(transitions["next"], self.agent.cumulants)
        rho = self.insert_rho(transitions) if self.predictive else torch.ones(len(transitions), 1, device=self.device)
        if self.scale.n_step > 1:
            transitions = transitions.clone(False)
            transitions.update(nstep_columns(transitions, self.scale.n_step, self.discount))
        self.replay.extend(compact(transitions, rho).to("cpu"))

    def add_crashes(self, transitions: TensorDictBase) -> None:
        """Keep copies of the steps before terminations in the crash memory (`scale.crash_memory`), if any."""
        if self.crashes is not None:
            rho = torch.ones(transitions.shape[0], 1)  # never sampled by rho
            self.crashes.extend(compact(transitions, rho).to("cpu"))

    def _uniform(self) -> TensorDictBase:
        """The uniform minibatch U (replay and crash memory together), expanded and mirrored."""
        stored = sample_uniform_with(self.replay, self.crashes, self.batch_size)
        batch = expand(stored)
        if self.scale.n_step > 1:  # DDPG's next state and reward become the n-step ones (learner.nstep)
            with_nstep_next(batch, stored, self.replay)
        return self._mirrored(batch.to(self.device))

    @property
    def ready(self) -> bool:
        """Warm-up done: enough transitions in the replay to start updating."""
        return len(self.replay) >= max(self.warmup, 1)

    def set_held_out(self, trajectory: TensorDictBase) -> None:
        """Time-ordered transitions (one or more whole episodes) for the prediction metric."""
        self.held_out = trajectory.to(self.device)

    # --- one update ------------------------------------------------------------------------
    def update(self) -> dict[str, float]:
        """One combined update; metrics every `metrics_every` updates, else an empty dict."""
        self._before_update()
        uniform = self._uniform()
        losses: dict[str, Tensor] = {}
        reward = ddpg_reward(uniform["next"], self.scale, self.discount, uniform.get(STEPS, None))
        if self.predictive:
            losses.update(self._representation_losses(uniform))
            ddpg_batch = phi_batch(self.nets.gvf, uniform, reward, keep_features=bool(self.offset_steer))
            if self.offset_steer and self.offset_steer.on(self.updates):
                losses.update(self.offset_steer(ddpg_batch, uniform["speed"], uniform["last_action"]))
        else:
            ddpg_batch = observation_batch(uniform, reward, lowdim=self.nets.representation == "lowdim")
        loss_ddpg, out = self.ddpg.loss(ddpg_batch)
        total = loss_ddpg + sum(v for k, v in losses.items() if "/" not in k)  # "x/y" names a diagnostic
        return self._apply(total, losses, out, ddpg_batch, uniform["alpha"])

    def update_representation(self) -> dict[str, float]:
        """Algorithm 2's update (offline): lines 11-17 alone, the GVFs and g without DDPG."""
        if not self.predictive:
            raise ValueError(f"agent {self.agent.name!r} learns no predictive representation")
        self._before_update()
        losses = self._representation_losses(self._uniform())
        return self._apply(sum(losses.values()), losses)

    def _before_update(self) -> None:
        if not self.ready:
            raise RuntimeError(f"warm-up: {len(self.replay)} of {self.warmup} transitions")
        if self.needs_warm_start:
            self.warm_start()  # a resumed core counts as warm: its g was trained
        self.warm = True
        every = self.agent.rho_refresh_every
        if self.predictive and every and self.updates and self.updates % every == 0:
            self.refresh_all_rho()

    def _apply(
        self,
        total: Tensor,
        losses: dict[str, Tensor],
        out: TensorDictBase | None = None,
        ddpg_batch: TensorDictBase | None = None,
        alpha: Tensor | None = None,
    ) -> dict[str, float]:
        """Backward, the finite check, the optimisers' steps (DDPG's only with its batch), metrics."""
        self._zero_grad()
        total.backward()
        if not self._finite(total):
            # never learn from a non-finite loss or gradient: the step is skipped and counted
            self.skipped_nonfinite += 1
            self._zero_grad()
            return {}
        report = (self.updates + 1) % self.agent.metrics_every == 0
        if report and ddpg_batch is not None:  # before the step: the gradient and actions that made it
            losses.update(actor_diagnostics(self.nets.actor, self.ddpg.loss_module.actor_network, ddpg_batch))
            losses.update(steering_diagnostics(*self.ddpg.action_gradient(ddpg_batch), alpha))  # alpha of its states
        self._step(ddpg=ddpg_batch is not None)
        self.updates += 1
        if not report:
            return {}
        return self._metrics(losses, out)

    @torch.no_grad()
    def _finite(self, total: Tensor) -> bool:
        """The loss and every gradient are finite (one host sync for all of them)."""
        params = (p for opt in self._optimizers() for group in opt.param_groups for p in group["params"])
        grads = [p.grad for p in params if p.grad is not None]
        return bool(torch.isfinite(total + torch.nn.utils.get_total_norm(grads)))

    def _representation_losses(self, uniform: TensorDictBase) -> dict[str, Tensor]:
        """Lines 11-17: the GVFs' TD loss on A ~ rho, the discriminator's BCE on U."""
        stored = self.replay.sample_by_rho(self.batch_size).to(self.device)
        batch = expand(stored)
        if self.agent.refresh_rho:  # the stored item's rho, so before mirroring
            self.replay.update_rho(stored["index"], self.rho(batch)[0])
        batch = self._mirrored(batch)
        with torch.no_grad():
            v_next = self.nets.gvf(*_obs(batch["next"]))
        target = td_target(
            cumulants(batch["next"], self.agent.cumulants),
            batch["next", "terminated"],
            v_next,
            self.gammas,
            self.agent.gvf_terminal,
            None if self.bound is None else self.bound.max_abs,
        )
        return {
            "td": gvf_loss(self.nets.gvf(*_obs(batch)), target, self.replay.rho_bar),
            "behaviour": behaviour_loss(self.nets.behaviour, _obs(uniform), uniform["action"], self.generator),
        }

    def _mirrored(self, batch: TensorDictBase) -> TensorDictBase:
        """`scale.mirror` of the items mirrored left-right, drawn independently per item."""
        if self.scale.mirror <= 0:
            return batch
        mask = torch.rand(batch.shape[0], generator=self.generator) < self.scale.mirror
        return mirror(batch, mask.to(self.device))

    def _optimizers(self) -> list[torch.optim.Optimizer]:
        extra = [self.gvf_optimizer, self.behaviour_optimizer] if self.predictive else []
        return extra + [self.ddpg.actor_optimizer, self.ddpg.critic_optimizer]

    def _zero_grad(self) -> None:
        for optimizer in self._optimizers():
            optimizer.zero_grad(set_to_none=True)

    def _step(self, ddpg: bool = True) -> None:
        if self.predictive:
            self.gvf_optimizer.step()
            self.behaviour_optimizer.step()
        if ddpg:
            self.ddpg.step()  # critic, actor (every td3_actor_delay-th with td3), then the targets
            if self.average is not None:
                self.average.update(self.nets.policy)

    def _metrics(self, losses: dict[str, Tensor], out: TensorDictBase | None) -> dict[str, float]:
        metrics = {name if "/" in name else f"losses/{name}": float(value.detach()) for name, value in losses.items()}
        if out is not None:  # DDPG's part of the update
            metrics.update(ddpg_metrics(out))
        metrics["train/updates"] = float(self.updates)
        metrics["train/replay_size"] = float(len(self.replay))
        if self.crashes is not None:
            metrics["train/crash_memory_size"] = float(len(self.crashes))
        metrics["train/skipped_nonfinite"] = float(self.skipped_nonfinite)
        if self.predictive:
            metrics["train/rho_bar"] = self.replay.rho_bar
            metrics.update(self.insert_rho.metrics())
            if self.held_out is not None:
                a = self.agent
                error = prediction_error(self.nets.gvf, self.held_out, a.cumulants, a.gammas, terminal=a.gvf_terminal)
                metrics.update(error)
        return metrics

    # --- weights and checkpoints ---------------------------------------------------------------
    def policy_state_dict(self) -> dict[str, Tensor]:
        """Weights of the acting network (`common.networks.make_policy`), for the actors: the
        online actor, or with `scale.act_with_target` DDPG's Polyak-averaged target actor."""
        if not self.scale.act_with_target:
            return self.nets.policy.state_dict()
        loss = self.ddpg.loss_module
        with loss.target_actor_network_params.to_module(loss.actor_network):
            return {k: v.detach().clone() for k, v in self.nets.policy.state_dict().items()}

    def deployed_state_dict(self) -> dict[str, Tensor]:
        """The policy a checkpoint keeps and the evaluator drives: `scale.policy_average`'s, else the acting one."""
        return self.average.policy_state_dict() if self.average is not None else self.policy_state_dict()

    def broadcast_state_dict(self, with_behaviour: bool = False) -> dict[str, Tensor]:
        """What the weights message carries: the acting network, the averaged one under `average.`
        names (`scale.policy_average`), and with `with_behaviour` (`learner.rho_at=actor`) the
        discriminator under `behaviour.` names, for actors that compute log mu_hat."""
        state = dict(self.policy_state_dict())
        if self.average is not None:
            state.update({f"{AVERAGE}{k}": v for k, v in self.average.policy_state_dict().items()})
        if with_behaviour:
            if not self.predictive:
                raise ValueError("learner.rho_at=actor needs a GVF variant: this agent has no discriminator")
            state.update({f"{BEHAVIOUR}{k}": v for k, v in self.nets.behaviour.state_dict().items()})
        return state

    def state_dict(self, with_replay: bool = False) -> dict[str, Any]:
        state = {name: module.state_dict() for name, module in self.nets.modules().items()}
        state.update(ddpg=self.ddpg.state_dict(), updates=self.updates, generator=self.generator.get_state())
        if self.average is not None:
            state["policy_average"] = self.average.state_dict()
        if self.bound is not None:
            state["return_bound"] = self.bound.max_abs
        if self.predictive:
            state["gvf_optimizer"] = self.gvf_optimizer.state_dict()
            state["behaviour_optimizer"] = self.behaviour_optimizer.state_dict()
        if with_replay:
            state["replay"] = self.replay.state_dict()
            if self.crashes is not None:
                state["crashes"] = self.crashes.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for name, module in self.nets.modules().items():
            module.load_state_dict(state[name])
        self.ddpg.load_state_dict(state["ddpg"])
        self.updates = state["updates"]
        self.warm = self.updates > 0
        self.generator.set_state(state["generator"])
        if self.average is not None and "policy_average" in state:
            self.average.load_state_dict(state["policy_average"])
        if self.bound is not None:  # an older checkpoint has none: the bound grows back as data arrives
            self.bound.max_abs = state.get("return_bound", self.bound.max_abs).to(self.device)
        if self.predictive:
            self.gvf_optimizer.load_state_dict(state["gvf_optimizer"])
            self.behaviour_optimizer.load_state_dict(state["behaviour_optimizer"])
        if "replay" in state:
            self.replay.load_state_dict(state["replay"])
        if "crashes" in state and self.crashes is not None:
            self.crashes.load_state_dict(state["crashes"])
