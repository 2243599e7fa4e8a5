"""rho = tau(a|s) / mu_hat(a|s) for the transitions entering the replay (Algorithm 1, lines 8-9),
and what the learner reports of it (train/rho_clip_rate, train/rho_actor_log_error).

mu_hat comes from the learner's discriminator g (`common.density.log_mu_hat` of g's logit), or,
with `learner.rho_at=actor`, from the log mu_hat that an actor computed with the g of its
weights and sent in the chunk: then only tau is computed here, and every `RHO_CHECK_EVERY`-th
such batch is checked against the learner's own g (what the actors' older g costs).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import Tensor, nn

from common.config.agent import AgentConfig
from learner.behaviour import log_mu_hat
from learner.gvf import importance_ratio, log_tau

RHO_SLICE = 256  # g's forward costs ~2x less per item in slices of 256 than at 2048 on CPU
RHO_CHECK_EVERY = 20  # actor-rho batches between checks against the learner's own g


class InsertRho:
    """rho of incoming transitions under `behaviour` (g), with the clip and actor-rho bookkeeping."""

    def __init__(self, agent: AgentConfig, behaviour: nn.Module):
        self.agent, self.behaviour = agent, behaviour
        self.seen = self.clipped = 0
        self.actor_batches = 0
        self.actor_error: list[float] = []

    @torch.no_grad()
    def by_g(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        """rho under the current g, clipped; and which ones were clipped."""
        return self.from_log_mu(td["action"], td["last_action"], self.log_mu(td))

    def log_mu(self, td: TensorDictBase) -> Tensor:
        """log mu_hat(a|s) under the current g."""
        return log_mu_hat(self.behaviour(td["image"], td["speed"], td["last_action"], td["action"]), td["action"])

    def from_log_mu(self, action: Tensor, last_action: Tensor, log_mu: Tensor) -> tuple[Tensor, Tensor]:
        return importance_ratio(log_tau(action, last_action, self.agent.tau_width), log_mu, self.agent.rho_max)

    @torch.no_grad()
    def __call__(self, transitions: TensorDictBase) -> Tensor:
        """rho (B, 1) of a batch entering D: from its finite "log_mu" items where given, else by g; clips counted."""
        rho, clipped = self._at_insert(transitions)
        self.seen += clipped.numel()
        self.clipped += int(clipped.sum())
        return rho

    def _at_insert(self, transitions: TensorDictBase) -> tuple[Tensor, Tensor]:
        log_mu = transitions.get("log_mu", None)
        if log_mu is None:
            return self._by_g_sliced(transitions)
        given = torch.isfinite(log_mu).reshape(-1)
        if bool(given.all()):  # the common case: no copy of the batch, tau alone
            self._check_actor_rho(transitions)
            return self.from_log_mu(transitions["action"], transitions["last_action"], log_mu)
        rho = torch.empty(transitions.shape[0], 1, device=log_mu.device)
        clipped = torch.empty(transitions.shape[0], 1, dtype=torch.bool, device=log_mu.device)
        if given.any():
            part = transitions[given]
            self._check_actor_rho(part)
            rho[given], clipped[given] = self.from_log_mu(part["action"], part["last_action"], part["log_mu"])
        rho[~given], clipped[~given] = self._by_g_sliced(transitions[~given])
        return rho, clipped

    def _by_g_sliced(self, transitions: TensorDictBase) -> tuple[Tensor, Tensor]:
        parts = [self.by_g(p) for p in transitions.split(RHO_SLICE)]
        return torch.cat([r for r, _ in parts]), torch.cat([c for _, c in parts])

    def _check_actor_rho(self, part: TensorDictBase) -> None:
        """Every `RHO_CHECK_EVERY`-th actor-rho batch: mean abs(log mu_actor - log mu_here) on up to 64 items."""
        self.actor_batches += 1
        if self.actor_batches % RHO_CHECK_EVERY != 1:
            return
        part = part[:64]
        self.actor_error.append(float((part["log_mu"] - self.log_mu(part)).abs().mean()))

    def metrics(self) -> dict[str, float]:
        """The clip rate since the last call, and the mean actor-rho error if any was checked; then reset."""
        out = {"train/rho_clip_rate": self.clipped / max(self.seen, 1)}
        if self.actor_error:
            out["train/rho_actor_log_error"] = sum(self.actor_error) / len(self.actor_error)
        self.seen = self.clipped = 0
        self.actor_error = []
        return out
