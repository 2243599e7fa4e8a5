"""What the learning core's tests share: the variants, a tiny scale, LaneDrive-shaped data."""

import torch

from common.config.agent import AgentConfig, ScaleConfig
from learner.core import LearningCore
from tests.fakes import collect

VARIANTS = {
    "gvf_ddpg": dict(representation="predictive"),
    "gvf_ddpg_g0": dict(representation="predictive", gammas=[0.0]),
    "gvf_ddpg_g095": dict(representation="predictive", gammas=[0.95]),
    "ddpg_image": dict(representation="image"),
    "ddpg_lowdim": dict(representation="lowdim"),
}
TINY = ScaleConfig(
    name="tiny",
    conv_channels=[4, 8, 8, 8, 8],
    gvf_hidden=[32, 32],
    behaviour_hidden=[32, 16],
    policy_hidden=[32, 16],
    image_policy_hidden=[32, 16],
    batch_size=16,
    buffer_size=300,
    warmup=200,
)
PAPER_RHO = dict(behaviour_warmup_updates=0, rho_refresh_every=0)  # rho fixed at insert (Algorithm 1)


def lanedrive_data():
    """400 transitions of 4 cars on the fake LaneDrive, time-major per car."""
    return collect(4, 100, seed=0).reshape(-1)


def make_core(variant: str, seed: int = 0, **agent_overrides) -> LearningCore:
    torch.set_num_threads(1)
    agent = AgentConfig(name=variant, **{**VARIANTS[variant], "metrics_every": 2, "lr_actor": 1e-3, **agent_overrides})
    return LearningCore(agent, TINY, seed=seed)
