"""Left-right mirroring of sampled transitions (learner/mirror.py, `scale.mirror`): the right
fields change sign, the simulator really is mirror-symmetric, and the learner applies it."""

import dataclasses

import numpy as np
import pytest
import torch

from actors.envs.sim import LaneDriveSim
from common.config.agent import AgentConfig
from common.config.env import EnvConfig
from learner.core import LearningCore
from learner.mirror import mirror
from learner.replay import compact, expand
from tests.core_fixtures import TINY
from tests.fakes import collect
from tests.helpers import compose_run


@pytest.fixture(scope="module")
def batch():
    """An expanded minibatch, as the learner samples it."""
    data = collect(4, 60, seed=0).reshape(-1)
    return expand(compact(data, torch.ones(data.shape[0])))


def test_mirror_flips_only_the_chosen_items_and_leaves_the_input_alone(batch):
    before = batch.clone()
    mask = torch.arange(batch.shape[0]) % 2 == 0
    out = mirror(batch, mask)
    assert (batch == before).all()
    sign = torch.where(mask, -1.0, 1.0).reshape(-1, 1)
    for key in ("image", ("next", "image")):
        assert torch.equal(out[key][mask], batch[key][mask].flip(-1))
        assert torch.equal(out[key][~mask], batch[key][~mask])
    for key in ("alpha", "beta", ("next", "alpha"), ("next", "beta")):
        assert torch.equal(out[key], batch[key] * sign)
    for key in ("action", "last_action", ("next", "last_action")):
        assert torch.equal(out[key][:, :1], batch[key][:, :1] * sign)  # steering
        assert torch.equal(out[key][:, 1:], batch[key][:, 1:])  # target speed
    for key in ("speed", ("next", "speed"), ("next", "reward"), ("next", "terminated")):
        assert torch.equal(out[key], batch[key])
    again = mirror(out, mask)  # mirroring twice is the identity
    assert all(torch.equal(again[k], batch[k]) for k in batch.keys(True, True))


@pytest.mark.parametrize("lateral, yaw", [(1.0, 0.1), (2.0, 0.0), (-1.5, 0.08)])
def test_the_flipped_frame_is_the_frame_of_the_mirrored_pose(lateral, yaw):
    sim = LaneDriveSim(EnvConfig.from_kwargs(track="dune", lighting=False), 1)
    sim.reset(0, np.random.default_rng(0), {"track": "dune", "random_start": False})
    s = float(np.argmin(np.abs(sim.tracks[0].curvature))) * sim.tracks[0].spacing  # a straight
    sim.place(0, s, lateral, yaw)
    frame, info = sim.frames[0, 0].astype(int), sim.info(0)
    sim.place(0, s, -lateral, -yaw)
    mirrored, info_m = sim.frames[0, 0].astype(int), sim.info(0)
    assert info_m["alpha"] == pytest.approx(-info["alpha"], abs=1e-6)
    assert info_m["beta"] == pytest.approx(-info["beta"], abs=1e-6)
    flipped_error = np.abs(frame[:, ::-1] - mirrored).mean()
    # only the grass texture differs: road and markings line up once flipped
    assert flipped_error < 0.5 * np.abs(frame - mirrored).mean()
    assert (np.abs(frame[:, ::-1] - mirrored) > 40).mean() < 0.05


def test_the_learner_mirrors_the_configured_fraction_of_each_minibatch(batch):
    agent = AgentConfig(name="gvf_ddpg", representation="predictive", metrics_every=1)
    steering = batch["action"][:, 0]
    assert (steering != 0).all()
    for fraction, low, high in ((0.0, 0, 0), (0.5, 0.35, 0.65), (1.0, 1, 1)):
        core = LearningCore(agent, dataclasses.replace(TINY, mirror=fraction), seed=0)
        flipped = (core._mirrored(batch)["action"][:, 0] == -steering).float().mean()
        assert low <= flipped <= high, (fraction, flipped)
    core = LearningCore(agent, dataclasses.replace(TINY, mirror=0.5, warmup=100), seed=0)
    core.add(collect(4, 60, seed=1).reshape(-1))
    for _ in range(3):
        metrics = core.update()
    assert np.isfinite(metrics["losses/td"]) and np.isfinite(metrics["losses/actor"])


def test_small_mirrors_half_the_paper_scale_none_and_a_bad_fraction_is_refused():
    assert compose_run(["scale=small"]).scale.mirror == 0.5
    assert compose_run(["scale=paper"]).scale.mirror == 0.0
    with pytest.raises(ValueError, match="scale.mirror"):
        compose_run(["scale.mirror=1.5"])


def test_an_odd_gvf_negates_every_prediction_under_the_mirror_and_the_learner_trains_it(batch):
    from common.networks import GVFNetwork, make_gvf

    torch.manual_seed(0)
    image, speed, last = batch["image"][:8], batch["speed"][:8], batch["last_action"][:8]
    odd = GVFNetwork(TINY.conv_channels, [16], 4, odd=True)
    mirrored_last = torch.cat([-last[:, :1], last[:, 1:]], -1)
    assert torch.allclose(odd(image.flip(-1), speed, mirrored_last), -odd(image, speed, last), atol=1e-6)
    plain = GVFNetwork(TINY.conv_channels, [16], 4)
    plain.load_state_dict(odd.state_dict(), strict=False)  # the same weights, without the construction
    assert not torch.allclose(plain(image.flip(-1), speed, mirrored_last), -plain(image, speed, last), atol=1e-3)
    with pytest.raises(RuntimeError, match="mirror_last"):  # a checkpoint of the other kind is refused
        plain.load_state_dict(odd.state_dict())
    agent = AgentConfig(name="gvf_ddpg", representation="predictive", metrics_every=1)
    with pytest.raises(ValueError, match="scale.mirror_gvf"):
        make_gvf(dataclasses.replace(agent, cumulants=["alpha", "speed"]), dataclasses.replace(TINY, mirror_gvf=True))
    core = LearningCore(agent, dataclasses.replace(TINY, mirror_gvf=True, warmup=100), seed=0)
    assert core.nets.gvf.mirror_last is not None
    core.add(collect(4, 60, seed=1).reshape(-1))
    before = [p.detach().clone() for p in core.nets.gvf.parameters()]
    for _ in range(3):
        metrics = core.update()
    assert np.isfinite(metrics["losses/td"]) and np.isfinite(metrics["losses/actor"])
    assert any(not torch.equal(b, p) for b, p in zip(before, core.nets.gvf.parameters()))
