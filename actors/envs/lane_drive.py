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
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from actors.envs.camera import HEIGHT, WIDTH
from actors.envs.sim import LaneDriveSim
from actors.envs.topdown import render_topdown
from common.config.env import EnvConfig


def observation_space() -> gym.spaces.Dict:
    return gym.spaces.Dict(
        {
            "image": gym.spaces.Box(0, 255, (2, HEIGHT, WIDTH), np.uint8),
            "speed": gym.spaces.Box(0.0, 1.0, (1,), np.float32),
            "last_action": gym.spaces.Box(-1.0, 1.0, (2,), np.float32),
        }
    )


def action_space() -> gym.spaces.Box:
    return gym.spaces.Box(-1.0, 1.0, (2,), np.float32)


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


class LaneDriveVectorEnv(VectorEnv):
    """`num_envs` cars stepped together; a finished car is reset in the same step and its last
    observation and info are returned in ``info['final_obs']`` / ``info['final_info']``."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10, "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(
        self,
        num_envs: int,
        render_mode: str | None = None,
        track_chooser: Callable[[int], str] | None = None,
        on_episode_end: Callable[[int, dict], None] | None = None,
        **kwargs: Any,
    ) -> None:
        """`track_chooser(i)`, if given, names the road for car i at each of its resets (priority track sampling);
        `on_episode_end(i, final_info_i)` is told of car i's finished episode before that car's next road is chosen."""
        self.cfg = EnvConfig.from_kwargs(**kwargs)
        self.track_chooser, self.on_episode_end = track_chooser, on_episode_end
        self.num_envs = num_envs
        self.render_mode = render_mode
        self.sim = LaneDriveSim(self.cfg, num_envs)
        self.single_observation_space = observation_space()
        self.single_action_space = action_space()
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._rngs = [np.random.default_rng(s) for s in np.random.SeedSequence().spawn(num_envs)]

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        if seed is not None:
            seeds = seed if isinstance(seed, list) else [seed + i for i in range(self.num_envs)]
            self._rngs = [np.random.default_rng(s) for s in seeds]
        for i in range(self.num_envs):
            self._reset_car(i, options)
        return self.sim.observation(), self._infos()

    def step(self, actions):
        terminated, truncated = self.sim.step(actions)
        reward = self.sim.reward.copy()
        infos = self._infos()
        done = terminated | truncated
        if done.any():
            final_obs = self.sim.observation()
            infos["final_obs"] = np.array(
                [{k: v[i] for k, v in final_obs.items()} if done[i] else None for i in range(self.num_envs)],
                dtype=object,
            )
            infos["_final_obs"] = done.copy()
            infos["final_info"] = {k: v.copy() for k, v in infos.items() if not k.startswith("_") and k != "final_obs"}
            infos["_final_info"] = done.copy()
            for i in np.flatnonzero(done):
                if self.on_episode_end is not None:  # before the draw: the sampler must know this episode
                    self.on_episode_end(int(i), {k: v[i] for k, v in infos["final_info"].items()})
                self._reset_car(int(i), None)
            infos.update(self._infos())
        return self.sim.observation(), reward, terminated, truncated, infos

    def _reset_car(self, i: int, options: dict | None) -> None:
        if self.track_chooser is not None and not (options or {}).get("track"):
            options = {**(options or {}), "track": self.track_chooser(i)}
        self.sim.reset(i, self._rngs[i], options)

    def _infos(self) -> dict[str, np.ndarray]:
        per = [self.sim.info(i) for i in range(self.num_envs)]
        return {k: np.array([p[k] for p in per]) for k in per[0]}

    def render(self):
        if self.render_mode == "rgb_array":
            return np.stack([render_topdown(self.sim, i) for i in range(self.num_envs)])
        return None
