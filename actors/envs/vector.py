"""The same-step-autoreset vector env shared by LaneDrive and TORCS: N cars of one batched
simulator stepped together, a finished car reset in the same step (gymnasium's SAME_STEP mode).

A simulator here has `observation()`, `step(actions) -> (terminated, truncated)`, a `reward`
array, `info(i)` and `reset(i, rng, options)`; LaneDriveSim and TorcsSim both do.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from actors.envs.spaces import action_space, observation_space


class SameStepVectorEnv(VectorEnv):
    """`num_envs` cars stepped together; a finished car is reset in the same step and its last
    observation and info are returned in ``info['final_obs']`` / ``info['final_info']``."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10, "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(
        self,
        sim: Any,
        num_envs: int,
        render_mode: str | None,
        track_chooser: Callable[[int], str] | None,
        on_episode_end: Callable[[int, dict], None] | None,
    ) -> None:
        """`track_chooser(i)`, if given, names the road for car i at each of its resets (priority track sampling);
        `on_episode_end(i, final_info_i)` is told of car i's finished episode before that car's next road is chosen."""
        self.sim, self.num_envs, self.render_mode = sim, num_envs, render_mode
        self.track_chooser, self.on_episode_end = track_chooser, on_episode_end
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
