"""The acting network of a `gvf-offline` checkpoint, which `gvf-eval` drives like any other:
GVF-BCQ acts with BCQ on phi(s) = [v(s), speed, last action] of the frozen GVFs, E2E-BCQ with
BCQ on the flat observation (`common.bcq_networks.flat_observation`).

A gvf-offline checkpoint holds `common.checkpoint.policy_entries` ("policy" is this module's
`state_dict`, "agent", "scale", "core") plus "offline": {"method", "build"}, the arguments
that rebuild the networks (`make_offline_policy`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor, nn

from common.bcq_networks import BCQPolicy, flat_observation, make_bcq_networks
from common.config.agent import AgentConfig, ScaleConfig
from common.networks import GVFNetwork, make_gvf, n_predictions, phi

METHODS = ("gvf_bcq", "e2e_bcq")


class OfflinePolicy(nn.Module):
    """obs mapping (image, speed, last_action), one observation or a batch -> action."""

    def __init__(self, method: str, bcq: BCQPolicy, gvf: GVFNetwork | None = None):
        super().__init__()
        if method not in METHODS:
            raise ValueError(f"offline method must be one of {METHODS}, got {method!r}")
        self.method, self.bcq, self.gvf = method, bcq, gvf

    @torch.no_grad()
    def forward(self, obs: Mapping[str, Tensor]) -> Tensor:
        image, speed, last_action = obs["image"], obs["speed"], obs["last_action"]
        single = image.dim() == 3
        if single:
            image, speed, last_action = image[None], speed[None], last_action[None]
        if self.method == "gvf_bcq":
            state = phi(self.gvf(image, speed, last_action), speed, last_action)
        else:
            state = flat_observation(image, speed, last_action)
        action = self.bcq(state)
        return action[0] if single else action


def build_args(method: str, agent: AgentConfig, scale: ScaleConfig, **bcq: Any) -> dict[str, Any]:
    """What `make_offline_policy` needs, stored in the checkpoint's "offline" entry."""
    state_dim = n_predictions(agent) + 3 if method == "gvf_bcq" else 0
    image_channels = list(scale.conv_channels) if method == "e2e_bcq" else None
    return {"state_dim": state_dim, "image_channels": image_channels, **bcq}


def make_offline_policy(method: str, agent: AgentConfig, scale: ScaleConfig, build: dict[str, Any]) -> OfflinePolicy:
    """The networks of an offline policy, untrained (load its "policy" state_dict next)."""
    build = dict(build)
    n_samples = build.pop("n_samples", 10)
    vae, actor, critic = make_bcq_networks(**build)
    gvf = make_gvf(agent, scale) if method == "gvf_bcq" else None
    return OfflinePolicy(method, BCQPolicy(vae, actor, critic, n_samples), gvf)
