"""DDPG's minibatch, built from the uniform sample U (learner.core): phi(s) and phi(s') of the GVFs
for GVF-DDPG, the observation keys for the baselines; the reward in force (`scale.reward_scale`,
`scale.crash_penalty`); and with n-step returns the window's next state and reward (learner.nstep).
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor, nn

from common.config.agent import ScaleConfig, shaped_reward
from common.networks import phi
from learner.offset_steer import FEATURES
from learner.replay import FROM_CRASHES, ImportanceResamplingReplay, expand

STEPS = "steps_to_next_obs"  # torchrl's TD(0) estimator raises its gamma to this (learner.nstep)


def ddpg_reward(nxt: TensorDictBase, scale: ScaleConfig, discount: float, steps: Tensor | None = None) -> Tensor:
    """The env's reward, its offset term weighted (`scale.offset_weight`), less `scale.crash_penalty`
    where the car left the lane, scaled; with n-step windows (`steps` = m) the penalty is
    discounted to the window's last step."""
    terminated = nxt["terminated"].to(nxt["reward"].dtype)
    weight = 1.0 if steps is None else discount ** (steps.to(terminated.dtype) - 1)
    offset = nxt["speed"] * nxt["alpha"].abs()  # the observed speed is v / v_max
    return shaped_reward(nxt["reward"], terminated, offset, scale, weight)


def with_nstep_next(batch: TensorDictBase, stored: TensorDictBase, replay: ImportanceResamplingReplay) -> None:
    """Replace the expanded `batch`'s next state, reward and flags by its n-step window's (in place)."""
    nxt = expand(replay.bootstrap(stored))["next"]
    nxt["reward"] = stored["reward_n"]
    nxt["terminated"], nxt["truncated"] = stored["terminated_n"], stored["truncated_n"]
    nxt["done"] = nxt["terminated"] | nxt["truncated"]
    batch["next"] = nxt
    batch[STEPS] = stored[STEPS]


@torch.no_grad()
def phi_batch(gvf: nn.Module, uniform: TensorDictBase, reward: Tensor, keep_features: bool = False) -> TensorDict:
    """GVF-DDPG's batch on U with phi(s) and phi(s') of the current GVFs, detached (section 3);
    `keep_features` also keeps the trunk's features of s (learner.offset_steer)."""
    nxt = uniform["next"]
    # separate calls for s and s': one 2n batch is slower on CPU
    obs = (uniform["image"], uniform["speed"], uniform["last_action"])
    features, v = gvf.features_and_values(*obs) if keep_features else (None, gvf(*obs))
    v_next = gvf(nxt["image"], nxt["speed"], nxt["last_action"])
    batch = TensorDict(
        {
            "phi": phi(v, uniform["speed"], uniform["last_action"]),
            "action": uniform["action"],
            "next": {
                "phi": phi(v_next, nxt["speed"], nxt["last_action"]),
                "reward": reward,
                "done": nxt["done"],
                "terminated": nxt["terminated"],
            },
        },
        batch_size=[uniform.shape[0]],
    )
    if features is not None:
        batch[FEATURES] = features
    for key in (STEPS, FROM_CRASHES):
        if key in uniform.keys():
            batch[key] = uniform[key]
    return batch


def observation_batch(uniform: TensorDictBase, reward: Tensor, lowdim: bool) -> TensorDictBase:
    """The image baselines' batch: U itself with the reward in force (and DDPG-LowDim's (alpha, beta))."""
    uniform["next", "reward"] = reward
    if lowdim:
        for td in (uniform, uniform["next"]):
            td["lowdim"] = torch.cat([td["alpha"], td["beta"]], -1)
    return uniform
