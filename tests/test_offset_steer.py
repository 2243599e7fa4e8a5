"""The actor's steering pulled by the predictions' model of it (learner/offset_steer.py,
`scale.actor_offset_weight`): it moves the steering where the alpha predictions say the offset
goes to 0, trains only the actor, and refuses what it cannot read."""

import dataclasses

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from common.config.agent import AgentConfig, check_scale
from common.layers import LOW_DIM
from common.networks import BranchedActor, GVFNetwork
from learner.core import LearningCore
from learner.offset_steer import FEATURES, OffsetSteer
from tests.core_fixtures import TINY, lanedrive_data

N_PRED = 10  # alpha then beta at five gammas, cumulant-major


def linear_gvf(steer_gain: float = 0.8) -> tuple[GVFNetwork, torch.Tensor]:
    """A GVF whose head is linear: every alpha prediction is steer_gain * last steering - f . u, so
    the steering that zeroes it is f . u / steer_gain; beta's predictions are 0."""
    torch.manual_seed(0)
    gvf = GVFNetwork([4, 8, 8, 8, 8], [16], N_PRED)
    n_features = gvf.trunk.out_dim
    gvf.head = nn.Linear(n_features + LOW_DIM, N_PRED)
    u = torch.randn(n_features) * 0.1
    with torch.no_grad():
        gvf.head.weight.zero_(), gvf.head.bias.zero_()
        gvf.head.weight[:5, :n_features] = -u
        gvf.head.weight[:5, n_features + 1] = steer_gain  # [features, speed, last steering, last speed]
    return gvf, u


def batch(gvf: GVFNetwork, n: int = 64) -> tuple[TensorDict, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(1)
    features = torch.randn(n, gvf.trunk.out_dim, generator=g)
    speed, last = torch.rand(n, 1, generator=g), torch.rand(n, 2, generator=g) * 2 - 1
    phi = torch.cat([features[:, :6], speed, last], -1)  # the actor needs to see what sets the offset
    return TensorDict({"phi": phi, FEATURES: features}, [n]), speed, last


def test_the_term_moves_the_steering_to_where_the_predicted_offset_is_zero_and_not_the_gvf():
    gvf, u = linear_gvf()
    td, speed, last = batch(gvf)
    # the zeroing steering must be reachable inside [-1, 1] and readable from phi
    u[6:] = 0
    with torch.no_grad():
        gvf.head.weight[:5, 6 : gvf.trunk.out_dim] = 0
    target = td[FEATURES] @ u / 0.8
    actor = BranchedActor(td["phi"].shape[-1], [64, 64], n_actions=2)
    steer = OffsetSteer(gvf, actor, columns=[2, 3, 4], weight=1.0)
    optimizer = torch.optim.Adam(actor.parameters(), lr=3e-3)
    before = (actor(td["phi"])[:, 0] - target).abs().mean().item()
    for _ in range(400):
        optimizer.zero_grad()
        loss = steer(td, speed, last)["actor_offset"]
        loss.backward()
        optimizer.step()
    after = (actor(td["phi"])[:, 0] - target).abs().mean().item()
    print(f"mean abs(steering - zeroing steering): {before:.3f} -> {after:.3f}")
    assert after < 0.2 * before
    assert all(p.grad is None for p in gvf.parameters())


def test_only_the_steering_is_replaced_the_speed_action_stays_the_last_one():
    gvf, _ = linear_gvf(steer_gain=0.0)
    with torch.no_grad():
        gvf.head.weight.zero_()
        gvf.head.weight[2, -1] = 1.0  # alpha at the third gamma reads the last speed action only
    td, speed, last = batch(gvf)
    actor = BranchedActor(td["phi"].shape[-1], [16], n_actions=2)
    loss = OffsetSteer(gvf, actor, columns=[2], weight=2.0)(td, speed, last)["actor_offset"]
    assert torch.allclose(loss, 2.0 * last[:, 1].pow(2).mean())
    loss.backward()
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in actor.parameters())


def test_the_guard_applies_the_term_only_where_the_prediction_slopes_the_simulators_way():
    gvf, _ = linear_gvf()
    with torch.no_grad():  # gamma column 3 turned: it slopes against the steering
        gvf.head.weight[3, gvf.trunk.out_dim + 1] = -0.8
    td, speed, last = batch(gvf)
    actor = BranchedActor(td["phi"].shape[-1], [16], n_actions=2)
    plain = OffsetSteer(gvf, actor, columns=[2, 3], weight=1.0)(td, speed, last)
    guarded = OffsetSteer(gvf, actor, columns=[2, 3], weight=1.0, guard=True)(td, speed, last)
    assert torch.allclose(guarded["diag/actor_offset_applies"], torch.tensor(0.5))
    only_true = OffsetSteer(gvf, actor, columns=[2], weight=0.5)(td, speed, last)["actor_offset"]
    assert torch.allclose(guarded["actor_offset"], only_true)  # the turned column adds nothing
    assert guarded["actor_offset"] < plain["actor_offset"] and "diag/actor_offset_applies" not in plain


def test_a_guarded_term_leaves_the_steering_alone_where_every_slope_has_turned():
    gvf, _ = linear_gvf(steer_gain=-0.8)
    td, speed, last = batch(gvf)
    actor = BranchedActor(td["phi"].shape[-1], [16], n_actions=2)
    out = OffsetSteer(gvf, actor, columns=[0, 1, 2], weight=1.0, guard=True)(td, speed, last)
    assert out["diag/actor_offset_applies"] == 0
    out["actor_offset"].backward()
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in actor.parameters())


def test_the_learning_core_applies_and_reports_the_term_from_the_scale():
    data = lanedrive_data()
    scale = dataclasses.replace(TINY, actor_offset_weight=1.0, actor_offset_gammas=[0.9, 0.97])
    core = LearningCore(AgentConfig(name="gvf_ddpg", metrics_every=1), scale, seed=0)
    assert core.offset_steer.columns.tolist() == [2, 4]
    core.add(data[:300])
    metrics = [core.update() for _ in range(3)]
    assert any(metrics) and all(m["losses/actor_offset"] > 0 for m in metrics if m)
    guarded = dataclasses.replace(scale, actor_offset_guard=True)
    core = LearningCore(AgentConfig(name="gvf_ddpg", metrics_every=1), guarded, seed=0)
    core.add(data[:300])
    metrics = [m for m in (core.update() for _ in range(3)) if m]
    assert metrics and all(0 <= m["diag/actor_offset_applies"] <= 1 for m in metrics)
    image = AgentConfig(name="ddpg_image", representation="image")
    assert LearningCore(image, scale, seed=0).offset_steer is None  # no predictions to read


def test_unnamed_gammas_read_each_variants_short_predictions_and_none_leaves_the_term_off():
    scale = dataclasses.replace(TINY, actor_offset_weight=1.0, actor_offset_gammas=None)
    check_scale(scale)
    five = LearningCore(AgentConfig(name="gvf_ddpg"), scale, seed=0).offset_steer
    assert five.columns.tolist() == [0, 1]  # alpha at gamma 0 and 0.5 of 0, 0.5, 0.9, 0.95, 0.97
    myopic = LearningCore(AgentConfig(name="gvf_ddpg_g0", gammas=[0.0]), scale, seed=0).offset_steer
    assert myopic.columns.tolist() == [0]
    assert LearningCore(AgentConfig(name="gvf_ddpg_g095", gammas=[0.95]), scale, seed=0).offset_steer is None


def test_the_term_starts_after_the_set_number_of_updates():
    data = lanedrive_data()
    scale = dataclasses.replace(TINY, actor_offset_weight=1.0, actor_offset_gammas=[0.9], actor_offset_after=2)
    core = LearningCore(AgentConfig(name="gvf_ddpg", metrics_every=1), scale, seed=0)
    core.add(data[:300])
    metrics = [core.update() for _ in range(4)]
    assert ["losses/actor_offset" in m for m in metrics] == [False, False, True, True]


def test_what_the_term_cannot_read_is_refused_naming_the_field():
    with pytest.raises(ValueError, match="scale.actor_offset_after must be >= 0"):
        check_scale(dataclasses.replace(TINY, actor_offset_after=-1))
    with pytest.raises(ValueError, match="scale.actor_offset_weight must be >= 0"):
        check_scale(dataclasses.replace(TINY, actor_offset_weight=-1.0))
    with pytest.raises(ValueError, match="scale.actor_offset_guard needs scale.actor_offset_weight > 0"):
        check_scale(dataclasses.replace(TINY, actor_offset_guard=True))
    with pytest.raises(ValueError, match="scale.actor_offset_gammas must name"):
        check_scale(dataclasses.replace(TINY, actor_offset_weight=1.0, actor_offset_gammas=[]))
    scale = dataclasses.replace(TINY, actor_offset_weight=1.0, actor_offset_gammas=[0.8])
    with pytest.raises(ValueError, match=r"scale.actor_offset_gammas \[0.8\] are not in agent.gammas"):
        LearningCore(AgentConfig(name="gvf_ddpg"), scale, seed=0)
    with pytest.raises(ValueError, match="needs the alpha cumulant"):
        LearningCore(
            AgentConfig(name="gvf_ddpg", cumulants=["beta"]), dataclasses.replace(scale, actor_offset_gammas=[0.9])
        )
    with pytest.raises(ValueError, match="mirror_gvf=false"):
        LearningCore(
            AgentConfig(name="gvf_ddpg"), dataclasses.replace(scale, actor_offset_gammas=[0.9], mirror_gvf=True)
        )
