"""The learner never learns from, publishes or checkpoints non-finite values, and resume refuses
a bad checkpoint for the newest good one."""

import logging

import torch

from common import checkpoint
from learner.service import LearnerService
from tests.core_fixtures import make_core
from tests.fakes import random_transitions
from tests.helpers import TINY, compose_run


def _finite(module) -> bool:
    return all(bool(torch.isfinite(p).all()) for p in module.parameters())


def test_a_poisoned_reward_skips_the_update_and_no_weight_becomes_non_finite():
    core = make_core("gvf_ddpg", behaviour_warmup_updates=0)
    data = random_transitions(300, seed=1)
    data["next", "reward"][::7] = 3e38  # finite on the wire, absurd: the critic's loss overflows
    core.add(data)
    for _ in range(10):
        core.update()
    assert core.skipped_nonfinite > 0 and core.updates + core.skipped_nonfinite == 10
    assert all(_finite(m) for m in core.nets.modules().values())


def test_resume_refuses_a_non_finite_checkpoint_and_takes_the_newest_good_one(tmp_path, caplog):
    cfg = compose_run([*TINY, "transport=inproc", f"learner.checkpoint_dir={tmp_path}/ckpt"])
    good = LearnerService(cfg, None, tmp_path).save()
    state = checkpoint.load(good)
    state["core"]["updates"] = 7
    name = next(iter(state["core"]["actor"]))
    state["core"]["actor"][name].fill_(float("nan"))
    checkpoint.save(tmp_path / "ckpt", 7, state)
    assert checkpoint.newest_good(tmp_path / "ckpt")[0] == good
    with caplog.at_level(logging.ERROR):
        resumed = LearnerService(
            compose_run([*TINY, "transport=inproc", "resume=true", f"learner.checkpoint_dir={tmp_path}/ckpt"]),
            None,
            tmp_path,
        )
    assert resumed.core.updates == 0 and "non-finite values; refused" in caplog.text
    resumed.core.nets.actor.state_dict()[name].fill_(float("nan"))
    assert (
        resumed.save() is None and checkpoint.latest(tmp_path / "ckpt").name == "ckpt-000000007.pt"
    )  # nothing new written
