"""Ornstein-Uhlenbeck exploration noise (paper appendix, "GVF-DDPG Training": as in
Lillicrap et al. 2016, with theta = 1.0, sigma = 0.1, dt = 0.01).

Euler-Maruyama step of dx = theta (mu - x) dt + sigma dW, one independent process per
environment and action dimension:

    x <- x + theta (mu - x) dt + sigma sqrt(dt) N(0, 1).

The stationary standard deviation is sigma / sqrt(2 theta) (0.0707 with the paper's values)
and the correlation after k steps is (1 - theta dt)^k ~ exp(-theta dt k), a gradual
wander. `reset(mask)` restarts the processes of the environments that ended an episode.
"""

from __future__ import annotations

import numpy as np


class OrnsteinUhlenbeck:
    """OU noise of shape (n_envs, action_dim), numpy, float32; theta and sigma scalars or one per action."""

    def __init__(
        self,
        n_envs: int,
        action_dim: int = 2,
        *,
        theta: float | np.ndarray = 1.0,
        sigma: float | np.ndarray = 0.1,
        dt: float = 0.01,
        mu: float = 0.0,
        seed: int | None = None,
    ):
        self.theta, self.sigma, self.dt, self.mu = theta, sigma, dt, mu
        self.rng = np.random.default_rng(seed)
        self.state = np.full((n_envs, action_dim), mu, dtype=np.float32)

    def sample(self) -> np.ndarray:
        """Advance every process one step and return the new noise (a copy)."""
        drift = self.theta * (self.mu - self.state) * self.dt
        shock = self.sigma * np.sqrt(self.dt) * self.rng.standard_normal(self.state.shape)
        self.state = (self.state + drift + shock).astype(np.float32)
        return self.state.copy()

    def reset(self, mask: np.ndarray | None = None) -> None:
        """Restart the processes of the environments in `mask` (bool (n_envs,)), or all."""
        if mask is None:
            self.state[:] = self.mu
        else:
            self.state[np.asarray(mask, dtype=bool)] = self.mu
