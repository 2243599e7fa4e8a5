"""Policies the evaluator can drive: the kinematic controller, or the acting network of a
learner or gvf-offline checkpoint (which stores the policy weights with what built them)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from actors.controllers.kinematic import KinematicController
from common import checkpoint
from common.config.agent import AgentConfig, ScaleConfig
from common.config.env import VehicleConfig
from common.networks import make_policy
from common.offline_policy import make_offline_policy


def kinematic_policy(vehicle: VehicleConfig | None = None):
    """The kinematic controller for `vehicle` (LaneDrive's car if None; TORCS needs torcs_vehicle)."""
    controller = KinematicController(vehicle)
    return lambda obs, info: controller.act(info)


def network_policy(policy: torch.nn.Module, lowdim: bool):
    """Deterministic acting (no exploration noise) on a batch of cars."""

    @torch.no_grad()
    def act(obs: dict, info: dict) -> np.ndarray:
        batch = {k: torch.from_numpy(np.asarray(obs[k])) for k in ("image", "speed", "last_action")}
        if lowdim:
            batch["alpha"] = torch.as_tensor(np.asarray(info["alpha"], np.float32)).reshape(-1, 1)
            batch["beta"] = torch.as_tensor(np.asarray(info["beta"], np.float32)).reshape(-1, 1)
        return np.clip(policy(batch).numpy(), -1.0, 1.0)

    return act


def known_config(schema, values: dict):
    """A config from a checkpoint's saved fields, skipping any this version no longer has (an older file still loads)."""
    names = {f.name for f in dataclasses.fields(schema)}
    return schema(**{k: v for k, v in values.items() if k in names})


def checkpoint_policy(path: str | Path):
    """The acting network saved in a learner checkpoint (file, or the newest in a folder)."""
    path = checkpoint.find(path)
    state = checkpoint.load(path)
    if "policy" not in state:
        raise ValueError(f"{path} holds no policy weights (written by an older learner?)")
    agent, scale = known_config(AgentConfig, state["agent"]), known_config(ScaleConfig, state["scale"])
    if "offline" in state:  # gvf-offline: GVF-BCQ or E2E-BCQ
        offline = state["offline"]
        policy = make_offline_policy(offline["method"], agent, scale, offline["build"]).eval()
        policy.load_state_dict(state["policy"])
        name = {"gvf_bcq": "GVF-BCQ", "e2e_bcq": "E2E-BCQ"}[offline["method"]]
        return network_policy(policy, False), {"path": str(path), "agent": name, "updates": state["core"]["updates"]}
    policy = make_policy(agent, scale).eval()
    policy.load_state_dict(state["policy"])
    return network_policy(policy, agent.representation == "lowdim"), {
        "path": str(path),
        "agent": agent.name,
        "updates": state["core"]["updates"],
    }
