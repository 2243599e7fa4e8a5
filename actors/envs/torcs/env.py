"""Gymnasium views of TORCS with LaneDrive's contract: one car (`TorcsDriveEnv`, ``TorcsDrive-v0``)
or N cars in N TORCS processes stepped together (`TorcsDriveVectorEnv`, same-step autoreset).

Observation, action and info are LaneDrive's (actors/envs/lane_drive.py), so every actor, controller
and learner runs on either simulator: ``image`` uint8 (2, 64, 128), ``speed`` (1,) = speed / v_max,
``last_action`` (2,); action (steering, +1 = full left lock; target speed, -1..1 -> 0.5..1.0 v_max);
info alpha, beta, speed, track, progress, lap_completed, curvature, curvature_ahead,
lane_half_width, station, steer, steps (plus TORCS's ``relaunched`` and ``damage``).

Options are EnvConfig's (common/config/env.py), read for TORCS: ``track`` names a road of
roads.json's split ('train', 'test', 'all') or any torcs-data road; ``max_steps``, ``random_start``,
``lighting``, ``camera_height`` and ``damage`` as LaneDrive; ``vehicle.v_max`` is the speed at
target-speed action +1 (default 20 m/s = 72 km/h, LaneDrive's: the same observation scale on both
simulators, and the slowest target, 10 m/s, takes torcs-data's tightest 10 m bends within
car1-trb1's grip). TORCS's own physics replace the other vehicle fields; ``direction`` and
``lane_width`` do not apply (a TORCS road is driven its own way, and its lane is the whole road).
``torcs_vehicle(v_max)`` describes the car for the kinematic controller and the MPC.

    import gymnasium as gym, actors.envs
    env = gym.make("TorcsDrive-v0", track="test")
    envs = gym.make_vec("TorcsDrive-v0", num_envs=2, vectorization_mode="vector_entry_point")
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import gymnasium as gym
import numpy as np

from actors.envs.spaces import action_space, observation_space
from actors.envs.torcs.protocol import TorcsError, default_prefix, find_install
from actors.envs.torcs.sim import TorcsSim, torcs_vehicle
from actors.envs.vector import SameStepVectorEnv
from common.config.env import EnvConfig

__all__ = ["TorcsDriveEnv", "TorcsDriveVectorEnv", "torcs_vehicle"]
TORCS_ID = "TorcsDrive-v0"


def _config(kwargs: dict) -> EnvConfig:
    kwargs.pop("id", None)  # Hydra's env group carries the gymnasium id; this env is always TORCS
    return EnvConfig.from_kwargs(id=TORCS_ID, **kwargs)


def make_sim(cfg: EnvConfig, n: int, prefix: str | Path | None = None) -> TorcsSim:
    """`n` cars, one TORCS process each, refused with `make torcs` in the message when TORCS is not built."""
    install = find_install(Path(prefix) if prefix else None)
    if install is None:
        raise TorcsError(f"no TORCS under {prefix or default_prefix()}: run `make torcs`")
    return TorcsSim(cfg, n, install)


class TorcsDriveEnv(gym.Env):
    """One car in one TORCS process (see the module docstring for the spaces)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None, prefix: str | Path | None = None, **kwargs: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.cfg = _config(kwargs)
        self.render_mode = render_mode
        self.sim = make_sim(self.cfg, 1, prefix)
        self.vehicle = torcs_vehicle(self.cfg.vehicle.v_max)
        self.observation_space = observation_space()
        self.action_space = action_space()

    def _obs(self) -> dict[str, np.ndarray]:
        return {k: v[0] for k, v in self.sim.observation().items()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.sim.reset(0, self.np_random, options)
        return self._obs(), self.sim.info(0)

    def step(self, action):
        terminated, truncated = self.sim.step(np.asarray(action)[None])
        return self._obs(), float(self.sim.reward[0]), bool(terminated[0]), bool(truncated[0]), self.sim.info(0)

    def render(self):
        if self.render_mode == "rgb_array":  # the camera's current frame, as RGB
            return np.repeat(self.sim.frames[0, 0][:, :, None], 3, axis=2)
        return None

    def close(self) -> None:
        self.sim.close()


class TorcsDriveVectorEnv(SameStepVectorEnv):
    """`num_envs` cars in as many TORCS processes, stepped together; a finished car is reset in the
    same step and its last observation and info are returned in ``info['final_obs']`` / ``info['final_info']``."""

    def __init__(
        self,
        num_envs: int,
        render_mode: str | None = None,
        track_chooser: Callable[[int], str] | None = None,
        on_episode_end: Callable[[int, dict], None] | None = None,
        prefix: str | Path | None = None,
        **kwargs: Any,
    ) -> None:
        """`track_chooser` and `on_episode_end` as SameStepVectorEnv's; `prefix` is TORCS's install, `kwargs` EnvConfig's."""
        self.cfg = _config(kwargs)
        super().__init__(make_sim(self.cfg, num_envs, prefix), num_envs, render_mode, track_chooser, on_episode_end)
        self.vehicle = torcs_vehicle(self.cfg.vehicle.v_max)

    def render(self):
        if self.render_mode == "rgb_array":
            return np.repeat(self.sim.frames[:, 0][..., None], 3, axis=3)
        return None

    def close_extras(self, **kwargs: Any) -> None:
        self.sim.close()
