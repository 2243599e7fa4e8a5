"""Behaviour estimation by the density ratio trick (paper section 2.1, eqs. 6-7;
Algorithm 1, lines 8 and 15-17).

A discriminator g(a, s) is trained with binary cross-entropy to tell recorded pairs
(s, a ~ mu) (label 1) from pairs (s, a ~ eta) (label 0), eta uniform on the action box
[-1, 1]^2. With equal class priors (exactly half of each minibatch is relabelled),
mu(a|s) / eta(a|s) = g / (1 - g): `common.density.log_mu_hat` turns g's logit into log mu_hat.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor

from common.density import ACTION_HIGH, ACTION_LOW, log_eta, log_mu_hat

__all__ = ["ACTION_HIGH", "ACTION_LOW", "log_eta", "log_mu_hat", "sample_eta", "relabel_half", "behaviour_loss"]


def sample_eta(n: int, action_dim: int = 2, *, device=None, generator: torch.Generator | None = None) -> Tensor:
    """a ~ eta: uniform on the action box."""
    u = torch.rand(n, action_dim, device=device, generator=generator)
    return ACTION_LOW + (ACTION_HIGH - ACTION_LOW) * u


def relabel_half(action: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor]:
    """Algorithm 1, lines 15-16: replace a random half of the actions by eta samples, label 0.

    Returns (actions, labels z) with z = 1 for recorded actions and 0 for eta samples.
    """
    n = action.shape[0]
    fake = torch.randperm(n, generator=generator, device="cpu")[: n // 2].to(action.device)
    z = torch.ones(n, 1, device=action.device)
    z[fake] = 0.0
    eta = sample_eta(n, action.shape[-1], generator=generator).to(action.device)
    return torch.where(z.bool(), action, eta), z


def behaviour_loss(
    g: Callable[..., Tensor], obs: tuple[Tensor, ...], action: Tensor, generator: torch.Generator | None = None
) -> Tensor:
    """Binary cross-entropy of g on a uniform minibatch with half its actions from eta.

    `g(*obs, action)` returns logits (B, 1); `obs` is the state part of its input.
    """
    mixed, z = relabel_half(action, generator)
    return F.binary_cross_entropy_with_logits(g(*obs, mixed), z)
