"""The acting step, free of any network: policy on a batch of observations plus OU noise.

Weights arrive as `common.wire.Weights` (name -> array, a version); until the first arrives
the actor has no policy and `ready` is False.
"""

from __future__ import annotations

import numpy as np
import torch

from actors.exploration import OrnsteinUhlenbeck
from common.config.agent import AgentConfig, ScaleConfig
from common.config.run import ActorConfig
from common.networks import make_policy
from common.wire import RejectCounter, Weights, WireError
from common.wire_rules import check_weights


class Acting:
    """Batched policy inference with per-env OU exploration (paper: theta 1.0, sigma 0.1, dt 0.01)."""

    def __init__(self, agent: AgentConfig, scale: ScaleConfig, actor: ActorConfig, n_envs: int, seed: int) -> None:
        self.policy = make_policy(agent, scale).eval()
        self.lowdim = agent.representation == "lowdim"
        self.noise = OrnsteinUhlenbeck(n_envs, 2, theta=actor.ou_theta, sigma=actor.ou_sigma, dt=actor.ou_dt, seed=seed)
        self.version, self.epoch = -1, None

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
        check_weights(weights, self.policy.state_dict())
        self.policy.load_state_dict({k: torch.from_numpy(np.array(v, copy=True)) for k, v in weights.tensors.items()})
        self.version, self.epoch = weights.version, weights.epoch
        return True

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
