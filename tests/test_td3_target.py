"""TD3's target with the twin critics blended (learner/td3_target.py, `scale.td3_target_min_weight`)."""

import dataclasses

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.objectives import ValueEstimators

from common.config.agent import check_scale
from learner.td3_target import BlendedTD3Loss
from tests.core_fixtures import TINY
from tests.test_ddpg import random_batch


class ConstantQ(nn.Module):
    def __init__(self, value: float):
        super().__init__()
        self.bias = nn.Parameter(torch.tensor([value]))

    def forward(self, obs, action):
        return self.bias.expand(len(obs), 1) + 0.0 * action[:, :1]


def loss_with(min_weight: float, discount: float = 0.9) -> BlendedTD3Loss:
    actor = TensorDictModule(nn.Linear(3, 2), in_keys=["phi"], out_keys=["action"])
    critics = [
        TensorDictModule(ConstantQ(v), in_keys=["phi", "action"], out_keys=["state_action_value"]) for v in (1.0, 3.0)
    ]
    loss = BlendedTD3Loss(actor, critics, bounds=(-1.0, 1.0), num_qvalue_nets=2, deactivate_vmap=True)
    loss.make_value_estimator(ValueEstimators.TD0, gamma=discount)
    loss.min_weight = min_weight
    return loss


def batch(n: int = 4) -> TensorDict:
    out = random_batch(n)
    out["next", "reward"].zero_()  # the target is then the discount times the bootstrap alone
    return out


@pytest.mark.parametrize(("weight", "bootstrap"), [(1.0, 1.0), (0.5, 2.0), (0.0, 3.0), (0.75, 1.5)])
def test_the_target_bootstraps_from_the_blend_of_the_twins_and_the_predictions_stay_each_critics(weight, bootstrap):
    out = loss_with(weight)(batch())
    assert torch.allclose(out["target_value"], torch.full((4,), 0.9 * bootstrap))
    assert torch.allclose(out["pred_value"].reshape(2, -1)[:, 0], torch.tensor([1.0, 3.0]))  # untouched


def test_a_blend_needs_the_twin_critics_and_a_weight_in_the_unit_interval():
    with pytest.raises(ValueError, match="td3_target_min_weight must be in"):
        check_scale(dataclasses.replace(TINY, td3=True, td3_target_min_weight=1.5))
    with pytest.raises(ValueError, match="td3_target_min_weight needs scale.td3"):
        check_scale(dataclasses.replace(TINY, td3=False, td3_target_min_weight=0.5))
