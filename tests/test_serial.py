"""transport=inproc: every role a thread of one process over the in-process transport."""

import re
import threading
from pathlib import Path

from common.launch import train
from tests.helpers import TINY, compose_run, run_inproc

ROOT = Path(__file__).resolve().parents[1]


def test_inproc_run_trains_in_one_process_and_stops_by_itself_at_max_updates(tmp_path):
    result, ended = run_inproc(["learner.max_updates=30", "scale.crash_memory=500", "scale.crash_steps=8"], tmp_path)
    assert ended, "the run did not end at learner.max_updates"
    assert not [t.name for t in threading.enumerate() if t.name in ("learner", "actor-0")]  # every role stopped
    watch = (ROOT / "docs" / "wire.md").read_text().split("## What an outside sender can watch")[1].split("##")[0]
    fields = set(re.findall(r"`([a-z_]+)`", watch.split("On the wire")[0])) - {"progress"}
    assert fields and fields <= set(result), fields - set(result)  # docs/wire.md names real progress fields
    assert result["updates"] >= 30
    assert result["inserted"] >= 64 and result["episodes"] > 0
    assert result["rejected"] == 0 and result["lost_chunks"] == 0
    assert result["policy_lag"] is not None
    assert 0 < result["crash_memory"] <= 500  # copies of the steps before the crashes
    assert (tmp_path / "checkpoints").is_dir() and any((tmp_path / "tb").iterdir())


def test_learner_rate_limit_pauses_the_actors_instead_of_piling_up_data(tmp_path):
    """samples_per_insert 64 at batch 32: each transition owes 2 updates, far more than a tiny
    learner keeps up with. With the flow limit the actor waits for the updates; without it
    the actor runs ahead."""
    base = [
        *TINY,
        "transport=inproc",
        "progress=false",
        "actors.count=1",
        "learner.samples_per_insert=64",
        "learner.max_updates=150",
        "max_seconds=90",
        "agent.behaviour_warmup_updates=0",
    ]  # its seconds before update 1 let the actor run on: not what this measures
    on = train(compose_run([*base, "learner.max_owed_updates=8"]), str(tmp_path / "on"), threading.Event())
    off = train(compose_run([*base, "learner.max_owed_updates=0"]), str(tmp_path / "off"), threading.Event())
    assert on["updates"] >= 150 and off["updates"] >= 150
    assert on["flow_pauses"] >= 1 and off["flow_pauses"] == 0
    needed = 64 + 150 * 32 / 64  # the warm-up, then batch / samples_per_insert per update
    # chunks (16 steps x 2 envs) sent before the pause arrives still land; measured 140
    assert on["inserted"] <= needed + 4 * 32, on
    assert off["inserted"] > 3 * on["inserted"], (on, off)  # measured 2,400


def test_the_actors_are_held_while_the_learner_warm_starts_its_discriminator(tmp_path):
    """g's warm start (agent.behaviour_warmup_updates) blocks the learner's loop: without a pause
    the actors ran on and the inbox overflowed (1,909 chunks dropped in a 15-minute run)."""
    overrides = [
        *TINY,
        "transport=inproc",
        "progress=false",
        "actors.count=1",
        "learner.max_updates=10",
        "learner.max_owed_updates=8",
        "agent.behaviour_warmup_updates=400",
    ]
    result = train(compose_run(overrides), str(tmp_path), threading.Event())
    assert result["updates"] >= 10 and result["flow_pauses"] >= 1
    needed = 64 + 10 * 32 / 4  # the warm-up, then batch / samples_per_insert per update
    # chunks (16 steps x 2 envs) sent before the pause arrives still land
    assert result["inserted"] <= needed + 4 * 32, result
