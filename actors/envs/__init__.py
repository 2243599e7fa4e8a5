"""The embedded lane-driving simulator. Importing this package registers ``LaneDrive-v0``, and
``TorcsDrive-v0`` (actors/envs/torcs/env.py; needs `make torcs` only when made, not to register).

import gymnasium as gym, actors.envs
env = gym.make("LaneDrive-v0", track="test", direction="ccw")
envs = gym.make_vec("LaneDrive-v0", num_envs=16, vectorization_mode="vector_entry_point")
"""

import gymnasium as gym

from actors.envs.lane_drive import LaneDriveEnv, LaneDriveVectorEnv
from actors.envs.tracks import get_track, track_names

__all__ = ["LaneDriveEnv", "LaneDriveVectorEnv", "get_track", "track_names"]

if "LaneDrive-v0" not in gym.registry:
    gym.register(
        id="LaneDrive-v0",
        entry_point="actors.envs.lane_drive:LaneDriveEnv",
        vector_entry_point="actors.envs.lane_drive:LaneDriveVectorEnv",
    )

# By entry-point strings only: nothing of TORCS is imported until an env is made.
if "TorcsDrive-v0" not in gym.registry:
    gym.register(
        id="TorcsDrive-v0",
        entry_point="actors.envs.torcs.env:TorcsDriveEnv",
        vector_entry_point="actors.envs.torcs.env:TorcsDriveVectorEnv",
    )
