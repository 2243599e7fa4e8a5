"""`scale.policy_average`: the learner keeps an exponential moving average of the acting network;
the evaluator drives it and checkpoints keep it, while actors explore with the online policy."""

import copy
import dataclasses

import pytest
import torch

from actors.acting import Acting
from common import checkpoint, wire
from common.config.agent import AgentConfig, check_scale
from common.config.run import ActorConfig
from learner.core import LearningCore
from learner.service import LearnerService
from tests.core_fixtures import TINY, lanedrive_data
from tests.helpers import TINY as TINY_RUN
from tests.helpers import compose_run

AGENT = AgentConfig(name="gvf_ddpg", lr_actor=1e-2, metrics_every=100)


@pytest.fixture(scope="module")
def data():
    return lanedrive_data()


def averaged_core(data, rate: float) -> LearningCore:
    torch.set_num_threads(1)
    core = LearningCore(AGENT, dataclasses.replace(TINY, policy_average=rate), seed=0)
    core.add(data[:300])
    return core


def close(a: dict, b: dict, atol: float = 1e-5) -> bool:
    return a.keys() == b.keys() and all(torch.allclose(a[k], b[k], atol=atol) for k in a)


def test_a_slow_average_stays_near_the_first_update_and_a_fast_one_follows_the_online_policy(data):
    slow, fast = averaged_core(data, 1e-7), averaged_core(data, 1 - 1e-7)
    for core in (slow, fast):
        core.update()
    first = copy.deepcopy(slow.nets.policy.state_dict())  # the average starts as a copy of it
    for _ in range(6):
        slow.update()
        fast.update()
    online = slow.nets.policy.state_dict()
    assert not close(first, online, atol=1e-4)  # the online policy moved on
    assert close(slow.deployed_state_dict(), first)
    assert close(fast.deployed_state_dict(), fast.nets.policy.state_dict())


def test_actors_load_the_online_policy_and_the_evaluator_the_average(data):
    core = averaged_core(data, 0.2)
    for _ in range(8):
        core.update()
    online, average = core.policy_state_dict(), core.deployed_state_dict()
    assert not close(online, average, atol=1e-6)
    msg = wire.Weights(core.updates, {k: v.numpy() for k, v in core.broadcast_state_dict().items()}, epoch=1)
    assert {k.removeprefix(wire.AVERAGE) for k in msg.tensors if k.startswith(wire.AVERAGE)} == set(online)
    actor = Acting(AGENT, core.scale, ActorConfig(), 1, seed=0)
    evaluator = Acting(AGENT, core.scale, ActorConfig(), 1, seed=0, deployed=True)
    assert actor.load(msg) and evaluator.load(msg)
    assert close(actor.policy.state_dict(), online, atol=0)
    assert close(evaluator.policy.state_dict(), average, atol=0)
    # a learner without the option sends no average: the evaluator drives the online policy
    plain = wire.Weights(core.updates, {k: v.numpy() for k, v in online.items()}, epoch=2)
    assert evaluator.load(plain) and close(evaluator.policy.state_dict(), online, atol=0)


def test_a_resumed_core_keeps_the_average(data):
    core = averaged_core(data, 0.2)
    for _ in range(4):
        core.update()
    resumed = averaged_core(data, 0.2)
    resumed.load_state_dict(core.state_dict())
    assert close(resumed.deployed_state_dict(), core.deployed_state_dict(), atol=0)
    resumed.update()  # the average goes on: a fresh one would start as a copy of the online policy
    assert not close(resumed.deployed_state_dict(), resumed.policy_state_dict(), atol=1e-6)


def test_the_learners_checkpoint_keeps_the_averaged_policy(tmp_path, data):
    cfg = compose_run([*TINY_RUN, "transport=inproc", "scale.policy_average=0.2"])
    service = LearnerService(cfg, None, tmp_path)
    service.core.add(data[:100])
    for _ in range(3):
        service.core.update()
    saved = checkpoint.load(service.save())["policy"]
    assert close(saved, service.core.deployed_state_dict(), atol=0)
    assert not close(saved, service.core.policy_state_dict(), atol=1e-6)


@pytest.mark.parametrize("rate", [-0.1, 1.0])
def test_a_rate_outside_0_1_is_refused_naming_the_field(rate):
    with pytest.raises(ValueError, match="scale.policy_average"):
        check_scale(dataclasses.replace(TINY, policy_average=rate))


def test_the_evaluator_keeps_the_online_policy_beside_the_average_and_drives_each(data):
    from actors.evaluation.evaluate import evaluate, summary
    from actors.evaluation.main import eval_env_kwargs
    from actors.evaluation.periodic import drive_online
    from actors.evaluation.policies import network_policy

    core = averaged_core(data, 0.2)
    for _ in range(8):
        core.update()
    msg = wire.Weights(core.updates, {k: v.numpy() for k, v in core.broadcast_state_dict().items()}, epoch=1)
    cfg = compose_run([*TINY_RUN, "scale.policy_average=0.2", "eval.online_too=true", "env.max_steps=25"])
    evaluator = Acting(AGENT, core.scale, ActorConfig(), 1, seed=0, deployed=True, keep_online=True)
    actor = Acting(AGENT, core.scale, ActorConfig(), 1, seed=0)  # what the actors explore with
    assert drive_online(evaluator, cfg) is None  # nothing loaded yet
    assert evaluator.load(msg) and actor.load(msg)
    assert close(evaluator.policy.state_dict(), core.deployed_state_dict(), atol=0)
    assert close(evaluator.online.state_dict(), actor.policy.state_dict(), atol=0)
    roads = (cfg.eval.split, tuple(cfg.eval.directions))
    online = drive_online(evaluator, cfg)
    assert online == summary(evaluate(network_policy(actor.policy, False), *roads, **eval_env_kwargs(cfg)))
    assert online != summary(evaluate(network_policy(evaluator.policy, False), *roads, **eval_env_kwargs(cfg)))
    # weights without an average: the evaluator drives the online policy once, not twice
    plain = wire.Weights(core.updates, {k: v.numpy() for k, v in core.policy_state_dict().items()}, epoch=2)
    assert evaluator.load(plain) and drive_online(evaluator, cfg) is None


def test_online_too_without_an_average_is_refused_naming_the_field():
    with pytest.raises(ValueError, match="eval.online_too"):
        compose_run([*TINY_RUN, "eval.online_too=true"])
