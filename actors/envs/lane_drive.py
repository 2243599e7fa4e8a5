"""Gymnasium views of the LaneDrive simulator: one car (`LaneDriveEnv`) or N cars in one
process stepped together (`LaneDriveVectorEnv`, same-step autoreset).

Observation: ``image`` uint8 (2, 64, 128) = current and previous grayscale front-camera frame,
``speed`` float32 (1,) = speed / v_max, ``last_action`` float32 (2,).
Action: box [-1, 1]^2 = (steering, +1 turns left; target speed, -1..1 -> 0.5..1.0 v_max).
info: alpha, beta, speed (m/s), track, progress (laps), lap_completed, curvature,
curvature_ahead (max |1/R| in the next 40 m), lane_half_width, station (arclength of the nearest
centreline sample, m), steer (wheel angle, rad), steps.
"""

from __future__ import annotations

from typing import Any, Callable

import gymnasium as gym
import numpy as np

from actors.envs.sim import LaneDriveSim
from actors.envs.spaces import action_space, observation_space
from actors.envs.topdown import render_topdown
from actors.envs.vector import SameStepVectorEnv
from common.config.env import EnvConfig


class LaneDriveEnv(gym.Env):
    """One car on a closed road with a front camera (see module docstring for the spaces)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.cfg = EnvConfig.from_kwargs(**kwargs)
        self.render_mode = render_mode
        self.sim = LaneDriveSim(self.cfg, 1)
        self.observation_space = observation_space()
        self.action_space = action_space()

    def _obs(self) -> dict[str, np.ndarray]:
        s = self.sim
        return {
            "image": s.frames[0].copy(),
            "speed": np.array([s.v[0] / self.cfg.vehicle.v_max], np.float32),
            "last_action": s.last_action[0].copy(),
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.sim.reset(0, self.np_random, options)
        return self._obs(), self.sim.info(0)

    def step(self, action):
        terminated, truncated = self.sim.step(np.asarray(action)[None])
        return self._obs(), float(self.sim.reward[0]), bool(terminated[0]), bool(truncated[0]), self.sim.info(0)

    def render(self):
        if self.render_mode == "rgb_array":
            return render_topdown(self.sim, 0)
        return None


class LaneDriveVectorEnv(SameStepVectorEnv):
    """`num_envs` cars in one process stepped together; a finished car is reset in the same step and its last
    observation and info are returned in ``info['final_obs']`` / ``info['final_info']``."""

    def __init__(
        self,
        num_envs: int,
        render_mode: str | None = None,
        track_chooser: Callable[[int], str] | None = None,
        on_episode_end: Callable[[int, dict], None] | None = None,
        **kwargs: Any,
    ) -> None:
        """`track_chooser` and `on_episode_end` as SameStepVectorEnv's; `kwargs` are EnvConfig's."""
        self.cfg = EnvConfig.from_kwargs(**kwargs)
        super().__init__(LaneDriveSim(self.cfg, num_envs), num_envs, render_mode, track_chooser, on_episode_end)

    def render(self):
        if self.render_mode == "rgb_array":
            return np.stack([render_topdown(self.sim, i) for i in range(self.num_envs)])
        return None
