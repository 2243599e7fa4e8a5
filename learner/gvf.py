"""Out-of-policy GVF learning by importance resampling (paper section 2, eqs. 1-5;
Algorithm 1, lines 6-9 and 13-14).

Predictive questions. Cumulants c_{t+1} are the lane centeredness alpha and the road
angle beta of the transition's *next* state, each scaled by (1 - gamma) so that every
prediction lives on the cumulant's own scale. A truncated episode keeps bootstrapping.
At termination (the car left the lane) the convention is `AgentConfig.gvf_terminal`:

- "zero" (default): the continuation is 0, the target (1 - gamma) c_T; k steps before a
  departure a gamma = 0.97 prediction then carries only (1 - gamma^k) of the deviation;
- "absorbing": the terminal state repeats its cumulant forever, so the target there is c_T
  and a departure k steps ahead weighs gamma^k on every prediction.

"absorbing" was the default for a while on the argument that it warns of an imminent exit;
measured, "zero" drove better: with it GVF-DDPG first lapped every test road on a seed where
"absorbing" never did in 15 minutes, and held its laps longer (docs/results.md). Predictions
are ordered cumulant-major: [alpha@gamma_1..gamma_G, beta@gamma_1..gamma_G].

8 versus 5: the appendix says "8 predictions: 4 of alpha, 4 of beta", then "each of the 5
predictions had different values of gamma: 0.0, 0.5, 0.9, 0.95, 0.97". We take both
cumulants at all five discounts, 2 x 5 = 10 predictions, by default (`AgentConfig.gammas`).

Target policy tau ("repeat the last action", paper section 3): a truncated normal on the
action box centred on the last action, independently per action dimension, with standard
deviation `tau_width` (default 0.1, 5% of the box's width): narrow enough to mean "keep
the action", wide enough that behaviour actions keep usable ratios (on LaneDrive the
kinematic controller with OU noise changes its action by about 0.05 (steering) and 0.2
(target speed) per step). rho = tau(a|s) / mu_hat(a|s) (Algorithm 1, line 9), clipped to
`rho_max`. Importance resampling corrects the action distribution only, not the state
distribution (paper, after eq. 2).

TD loss (eqs. 2-5): delta = v(s) - y, y = (1 - gamma) c + gamma_{t+1} v(s') with v(s')
from the current parameters and no gradient (no target network: tau is fixed). The loss
rho_bar * 0.5 * sum_k delta_k^2, averaged over a minibatch drawn with probability
rho_i / sum_j rho_j, has the importance-resampling gradient of eq. 5 for every GVF k.
Note that under Adam a constant factor on a loss barely changes the step; rho_bar
matters in scale only with plain SGD, as in the tests.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from common.config.agent import TERMINALS
from common.density import log_truncated_normal


def log_tau(action: Tensor, last_action: Tensor, width: float) -> Tensor:
    """log tau(a|s) (B, 1): truncated normal N(last_action, width^2) on the box, per dimension."""
    return log_truncated_normal(action, last_action, width)


def importance_ratio(log_tau_value: Tensor, log_mu_hat_value: Tensor, rho_max: float) -> tuple[Tensor, Tensor]:
    """rho = tau / mu_hat clipped to rho_max (Algorithm 1, line 9); returns (rho, was_clipped)."""
    rho = (log_tau_value - log_mu_hat_value).exp()
    clipped = rho > rho_max
    return rho.clamp(max=rho_max), clipped


def cumulants(next_state: Mapping[str, Tensor], names: Sequence[str]) -> Tensor:
    """c_{t+1} (B, C): the named signals of the next state, e.g. ("alpha", "beta")."""
    return torch.cat([next_state[name].reshape(-1, 1) for name in names], -1)


def expand_gammas(gammas: Sequence[float] | Tensor, n_cumulants: int) -> Tensor:
    """Per-prediction gamma (C*G,) in cumulant-major order."""
    return torch.as_tensor(gammas, dtype=torch.float32).repeat(n_cumulants)


def td_target(
    cumulant: Tensor,
    terminated: Tensor,
    next_predictions: Tensor,
    gammas: Tensor,
    terminal: str = "zero",
    bound: Tensor | None = None,
) -> Tensor:
    """y = (1 - gamma) c_{t+1} + gamma b_{t+1} for every (cumulant, gamma), where b is v(s_{t+1})
    without gradient, or at a termination c_{t+1} ("absorbing") or 0 ("zero").

    cumulant (B, C); terminated (B, 1) bool; next_predictions (B, C*G); gammas (C*G,) from
    `expand_gammas`; `bound` (C,), if given, clamps v(s_{t+1}) to +-bound per cumulant
    (`ReturnBound`): a (1 - gamma)-scaled return of a cumulant with |c| <= M lies in [-M, M].
    """
    if terminal not in TERMINALS:
        raise ValueError(f"terminal must be one of {TERMINALS}, got {terminal!r}")
    n_gammas = gammas.shape[0] // cumulant.shape[-1]
    c = cumulant.repeat_interleave(n_gammas, dim=-1)
    ended = terminated.reshape(-1, 1).bool()
    after = c if terminal == "absorbing" else torch.zeros_like(c)
    v_next = next_predictions.detach()
    if bound is not None:
        limit = bound.repeat_interleave(n_gammas)
        v_next = v_next.clamp(-limit, limit)
    bootstrap = torch.where(ended, after, v_next)
    return (1.0 - gammas) * c + gammas * bootstrap


class ReturnBound:
    """The largest |c| of each cumulant over every transition stored so far (`agent.gvf_bootstrap_bound`).
    A (1 - gamma)-scaled return is a weighted mean of cumulants (and 0 after a termination), so
    the true value lies in [-M, M]; clamping the bootstrap there cannot move a correct estimate and
    cuts the runaway of a GVF whose own predictions feed its targets (one diverged: docs/results.md)."""

    def __init__(self, n_cumulants: int, device: torch.device | str = "cpu") -> None:
        self.max_abs = torch.zeros(n_cumulants, device=device)

    def update(self, next_state: Mapping[str, Tensor], names: Sequence[str]) -> None:
        seen = cumulants(next_state, names).abs().amax(0)
        self.max_abs = torch.maximum(self.max_abs, seen.to(self.max_abs.device))


def gvf_loss(predictions: Tensor, target: Tensor, rho_bar: float | Tensor) -> Tensor:
    """rho_bar * mean_batch(0.5 * sum_k delta_k^2); gradient rho_bar * E_D[delta grad v] (eq. 5)."""
    delta = predictions - target.detach()
    return rho_bar * 0.5 * delta.square().sum(-1).mean()
