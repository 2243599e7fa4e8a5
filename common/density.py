"""Action densities on the box [-1, 1]^d. The behaviour density estimate mu_hat from the discriminator's logit (paper eq. 7), shared by
the learner (rho at insert) and, with `learner.rho_at=actor`, the actors (log mu_hat sent in
each chunk). With equal class priors mu / eta = g / (1 - g), eta uniform on the action box, so

    log mu_hat(a|s) = logit g(a, s) + log eta,

computed from the logit so that it stays finite where g saturates.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

ACTION_LOW, ACTION_HIGH = -1.0, 1.0  # the action box of the simulator contract


def log_eta(action: Tensor) -> Tensor:
    """log eta(a|s) (B, 1): the uniform density on the box, independent of s."""
    value = -action.shape[-1] * math.log(ACTION_HIGH - ACTION_LOW)
    return action.new_full((*action.shape[:-1], 1), value)


def log_mu_hat(g_logit: Tensor, action: Tensor) -> Tensor:
    """log mu_hat(a|s) = log(g / (1 - g)) + log eta = logit + log eta (paper eq. 7)."""
    return g_logit + log_eta(action)


_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def log_truncated_normal(action: Tensor, mean: Tensor, width: float) -> Tensor:
    """log density (B, 1) of a normal N(mean, width^2) truncated to the box, independent per
    dimension: the GVFs' target policy tau (`learner.gvf.log_tau`) and a collector's action noise."""
    mean = mean.clamp(ACTION_LOW, ACTION_HIGH)
    z = (action - mean) / width
    log_pdf = -0.5 * z.square() - math.log(width) - _LOG_SQRT_2PI
    mass = torch.special.ndtr((ACTION_HIGH - mean) / width) - torch.special.ndtr((ACTION_LOW - mean) / width)
    return (log_pdf - mass.log()).sum(-1, keepdim=True)
