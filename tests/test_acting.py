"""Weights adoption by the acting step (actors/acting.py): newer versions only within one learner
epoch, any version of a new epoch (a learner resumed from a checkpoint counts from it again)."""

import numpy as np
import pytest

from actors.acting import Acting
from common.config.agent import AgentConfig, ScaleConfig
from common.config.run import ActorConfig
from common.wire import RejectCounter, Weights, WireError, decode, encode


def weights(acting: Acting, version: int, epoch: int, fill: float) -> Weights:
    tensors = {k: np.full(tuple(v.shape), fill, np.float32) for k, v in acting.policy.state_dict().items()}
    return decode(encode(Weights(version, tensors, epoch=epoch)), expect=Weights)  # as received


def first_value(acting: Acting) -> float:
    return float(next(iter(acting.policy.state_dict().values())).flatten()[0])


@pytest.fixture
def acting() -> Acting:
    scale = ScaleConfig(
        name="t", conv_channels=[2, 2, 2, 2, 2], gvf_hidden=[8], behaviour_hidden=[8], policy_hidden=[8]
    )
    return Acting(AgentConfig(name="gvf_ddpg"), scale, ActorConfig(), 1, seed=0)


def test_only_newer_versions_of_the_same_epoch_are_adopted(acting):
    assert not acting.ready
    assert acting.load(weights(acting, 40, epoch=7, fill=0.1)) and acting.ready
    assert not acting.load(weights(acting, 40, epoch=7, fill=0.2))  # same version: a repeat
    assert not acting.load(weights(acting, 35, epoch=7, fill=0.3))  # late, out of order
    assert first_value(acting) == pytest.approx(0.1)
    assert acting.load(weights(acting, 41, epoch=7, fill=0.4))
    assert (acting.version, first_value(acting)) == (41, pytest.approx(0.4))


def test_a_resumed_learner_with_lower_versions_is_followed(acting):
    acting.load(weights(acting, 45, epoch=7, fill=0.1))
    assert acting.load(weights(acting, 40, epoch=8, fill=0.5))  # resumed from its checkpoint at 40
    assert (acting.version, acting.epoch, first_value(acting)) == (40, 8, pytest.approx(0.5))
    assert acting.load(weights(acting, 42, epoch=8, fill=0.6))


def test_weights_that_do_not_fit_or_are_not_finite_are_counted_and_dropped(acting):
    good = weights(acting, 3, epoch=1, fill=0.1)
    assert acting.load(good)
    rejects = RejectCounter()
    name, first = next(iter(good.tensors.items()))
    missing = Weights(4, {k: v for k, v in good.tensors.items() if k != name}, epoch=1)
    reshaped = Weights(5, {**good.tensors, name: np.zeros((1, *first.shape), np.float32)}, epoch=1)
    wide = Weights(6, {**good.tensors, name: first.astype(np.float64)}, epoch=1)
    poisoned = Weights(7, {**good.tensors, name: np.full(first.shape, np.nan, np.float32)}, epoch=1)
    for bad in (missing, reshaped, wide, poisoned):
        assert not acting.adopt(bad, rejects, "gvf/r/weights")
    assert rejects.counts == {"weights": 4}
    assert (acting.version, first_value(acting)) == (3, pytest.approx(0.1))  # the old policy kept
    with pytest.raises(WireError, match="missing"):
        acting.load(missing)


def test_an_integrating_actor_takes_its_increment_over_the_wire_and_steers_from_the_last_action():
    import dataclasses

    import torch

    from common.networks import make_policy

    scale = ScaleConfig(
        name="t", conv_channels=[2, 2, 2, 2, 2], gvf_hidden=[8], behaviour_hidden=[8], policy_hidden=[8]
    )
    scale = dataclasses.replace(scale, steer_increment=0.25)
    agent = AgentConfig(name="gvf_ddpg")
    learner_side = make_policy(agent, scale)
    tensors = {k: v.numpy() for k, v in learner_side.state_dict().items()}
    acting = Acting(agent, scale, ActorConfig(), 2, seed=0)
    assert acting.load(decode(encode(Weights(3, tensors, epoch=1)), expect=Weights))
    assert float(acting.policy.actor.steer_increment) == 0.25
    obs = {
        "image": np.zeros((2, 2, 64, 128), np.uint8),
        "speed": np.full((2, 1), 0.5, np.float32),
        "last_action": np.array([[0.6, 0.0], [-0.4, 0.0]], np.float32),
    }
    steer = acting.act(obs, {}, explore=False)[:, 0]
    with torch.no_grad():
        assert np.allclose(steer, learner_side({k: torch.from_numpy(v) for k, v in obs.items()}).numpy()[:, 0])
    assert np.allclose(steer, [0.6, -0.4], atol=0.02)  # near-zero initial output: the steering holds
    absolute = Acting(agent, dataclasses.replace(scale, steer_increment=0.0), ActorConfig(), 1, seed=0)
    rejects = RejectCounter()
    assert not absolute.adopt(decode(encode(Weights(3, tensors, epoch=1)), expect=Weights), rejects, "k")
