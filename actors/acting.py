"""The acting step, free of any network: policy on a batch of observations plus OU noise.

Weights arrive as `common.wire.Weights` (name -> array, a version); until the first arrives
the actor has no policy and `ready` is False. With `learner.rho_at=actor` they also carry the
behaviour discriminator (`behaviour.`-prefixed tensors): then `log_mu` gives each chunk's
log mu_hat, so the learner needs no discriminator forward at insert (issue: rho where it scales).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from actors.exploration import OrnsteinUhlenbeck
from common.config.agent import AgentConfig, ScaleConfig
from common.config.run import ActorConfig
from common.density import log_mu_hat
from common.networks import BehaviourNetwork, make_policy
from common.wire import AVERAGE, BEHAVIOUR, RejectCounter, TransitionChunk, Weights, WireError
from common.wire_quant import floats
from common.wire_rules import check_weights


def _tensors(arrays: dict) -> dict[str, torch.Tensor]:
    return {
        k: torch.from_numpy(np.array(v, dtype=np.float32)) for k, v in arrays.items()
    }  # float16 on the wire: acts in float32


def ou_parameters(actor: ActorConfig) -> tuple[np.ndarray, np.ndarray]:
    """(theta, sigma) per action (steering, target speed): each action's own where set."""

    def pick(own, shared):
        return own if own is not None else shared

    theta = [pick(actor.ou_steer_theta, actor.ou_theta), pick(actor.ou_speed_theta, actor.ou_theta)]
    sigma = [pick(actor.ou_steer_sigma, actor.ou_sigma), pick(actor.ou_speed_sigma, actor.ou_sigma)]
    return np.array(theta, np.float32), np.array(sigma, np.float32)


class Acting:
    """Batched policy inference with per-env OU exploration (paper: theta 1.0, sigma 0.1, dt 0.01)."""

    def __init__(
        self,
        agent: AgentConfig,
        scale: ScaleConfig,
        actor: ActorConfig,
        n_envs: int,
        seed: int,
        deployed: bool = False,
        keep_online: bool = False,
    ) -> None:
        self.policy = make_policy(agent, scale).eval()
        self.lowdim = agent.representation == "lowdim"
        theta, sigma = ou_parameters(actor)
        self.noise = OrnsteinUhlenbeck(n_envs, 2, theta=theta, sigma=sigma, dt=actor.ou_dt, seed=seed)
        self.version, self.epoch = -1, None
        self.predictive = agent.representation == "predictive"
        self._behaviour_shape = (scale.conv_channels, scale.behaviour_hidden)
        self.behaviour: BehaviourNetwork | None = None
        """The broadcast discriminator, once weights carried one."""
        self.deployed = deployed
        """Load the averaged policy (`AVERAGE` tensors, `scale.policy_average`) where weights carry
        one: the evaluator drives the policy a checkpoint keeps; actors explore with the online one."""
        self.online = make_policy(agent, scale).eval() if deployed and keep_online else None
        """`keep_online`: the online policy as well, where weights carried an average (`eval.online_too`)."""
        self.has_average = False
        """`keep_online`: whether the last weights loaded carried an average (then `online` holds theirs)."""

    @property
    def ready(self) -> bool:
        return self.version >= 0

    def load(self, weights: Weights) -> bool:
        """Adopt newer weights, or any from a new learner epoch (a resumed learner counts from its
        checkpoint); returns False (and keeps the old ones) for a stale set. A set that does not
        fit this policy (names, shapes, dtypes) or holds a non-finite value raises
        WireError('weights') before anything is loaded (`common.wire_rules.check_weights`)."""
        if weights.epoch == self.epoch and weights.version <= self.version:
            return False
        tensors = floats(weights.tensors, weights.quant)  # codes -> float32 only for a set it adopts
        online = {k: v for k, v in tensors.items() if not k.startswith((BEHAVIOUR, AVERAGE))}
        average = {k[len(AVERAGE) :]: v for k, v in tensors.items() if k.startswith(AVERAGE)}
        policy = average if self.deployed and average else online
        behaviour = {k[len(BEHAVIOUR) :]: v for k, v in tensors.items() if k.startswith(BEHAVIOUR)}
        check_weights(dataclasses.replace(weights, tensors=policy), self.policy.state_dict())
        keep_online = self.online is not None and policy is average
        if keep_online:
            check_weights(dataclasses.replace(weights, tensors=online), self.online.state_dict())
        g = None
        if behaviour:
            if not self.predictive:
                raise WireError("weights", "behaviour tensors for a policy without a discriminator")
            g = self.behaviour or BehaviourNetwork(*self._behaviour_shape).eval()
            check_weights(dataclasses.replace(weights, tensors=behaviour), g.state_dict())
        self.policy.load_state_dict(_tensors(policy))
        if keep_online:
            self.online.load_state_dict(_tensors(online))
        self.has_average = keep_online
        if g is not None:
            g.load_state_dict(_tensors(behaviour))
        self.behaviour = g  # a learner that stops sending it takes rho back
        self.version, self.epoch = weights.version, weights.epoch
        return True

    @torch.no_grad()
    def with_log_mu(self, chunk: TransitionChunk) -> TransitionChunk:
        """`chunk` with log mu_hat of each step under the broadcast discriminator (as the learner
        would compute it at insert), or unchanged while none was broadcast."""
        if self.behaviour is None:
            return chunk
        n, action = chunk.num_steps, torch.from_numpy(np.asarray(chunk.action))
        logit = self.behaviour(
            torch.from_numpy(chunk.observations()[:n]),
            torch.from_numpy(np.asarray(chunk.speed[:n])),
            torch.from_numpy(np.asarray(chunk.last_action[:n])),
            action,
        )
        log_mu = log_mu_hat(logit, action).reshape(-1).numpy().astype(np.float32)
        return dataclasses.replace(chunk, log_mu=log_mu, behaviour_version=self.version)

    def adopt(self, weights: Weights, rejects: RejectCounter, key: str) -> bool:
        """`load`, with a set that does not fit counted by `rejects` and dropped (the old one kept)."""
        try:
            return self.load(weights)
        except WireError as err:
            rejects.reject(err, key)
            return False

    @torch.no_grad()
    def act(self, obs: dict, info: dict, explore: bool = True) -> np.ndarray:
        """Actions (n_envs, 2) in [-1, 1] for a batch of observations."""
        batch = {k: torch.from_numpy(np.asarray(obs[k])) for k in ("image", "speed", "last_action")}
        if self.lowdim:
            batch["alpha"] = torch.as_tensor(np.asarray(info["alpha"], np.float32)).reshape(-1, 1)
            batch["beta"] = torch.as_tensor(np.asarray(info["beta"], np.float32)).reshape(-1, 1)
        action = self.policy(batch).numpy()
        if explore:
            action = action + self.noise.sample()
        return np.clip(action, -1.0, 1.0).astype(np.float32)

    def episode_ended(self, mask: np.ndarray) -> None:
        self.noise.reset(mask)
