"""The observation and action spaces every simulator of the project shares (LaneDrive, TORCS)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from actors.envs.camera import HEIGHT, WIDTH


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
