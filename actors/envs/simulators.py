"""Which simulator a run drives (``env.id``: LaneDrive-v0 or TorcsDrive-v0), in the terms the actor and
the evaluator need: its roads per split, its vector env and its car.

TORCS modules load only when a TORCS env is asked for, so LaneDrive runs never import them. On TORCS
the splits are roads.json's (actors/envs/torcs/roads.py): 'train' and 'all' less the validation roads
(a few train roads held out of sampling), 'test', and 'validation' where the best policy is chosen.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from common.config.env import EnvConfig, VehicleConfig

TORCS = "TorcsDrive-v0"


def is_torcs(env: EnvConfig) -> bool:
    return env.id == TORCS


def road_names(env: EnvConfig, split: str) -> list[str]:
    """The roads of `split` that a reset draws or an evaluation drives ('train', 'test' or 'all')."""
    if is_torcs(env):
        from actors.envs.torcs.roads import training_roads

        return training_roads(split)
    from actors.envs.tracks import track_names

    return track_names(split)


def known_roads(env: EnvConfig) -> set[str]:
    """Every road name of the simulator: what a track table from the learner may name."""
    if is_torcs(env):
        from actors.envs.torcs.roads import road_names as torcs_roads

        return set(torcs_roads("all"))
    from actors.envs.tracks import track_names

    return set(track_names("all"))


def vector_env(env: EnvConfig, num_envs: int, **hooks: Any):
    """`num_envs` cars of the simulator `env.id` names, with LaneDrive's vector contract (`hooks`:
    track_chooser, on_episode_end)."""
    options = dataclasses.asdict(env)
    options.pop("id")
    if is_torcs(env):
        from actors.envs.torcs.env import TorcsDriveVectorEnv

        return TorcsDriveVectorEnv(num_envs, **hooks, **options)
    from actors.envs.lane_drive import LaneDriveVectorEnv

    return LaneDriveVectorEnv(num_envs, **hooks, **options)


def vehicle(env: EnvConfig) -> VehicleConfig:
    """The car as the kinematic controller reads it: TORCS's car1-trb1 on TORCS, else the configured one."""
    if is_torcs(env):
        from actors.envs.torcs.sim import torcs_vehicle

        return torcs_vehicle(env.vehicle.v_max)
    return env.vehicle
