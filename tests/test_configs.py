"""Every config in conf/ composes against its schema; a bad value is refused naming the field."""

from pathlib import Path

import pytest
from hydra.errors import ConfigCompositionException
from omegaconf.errors import ValidationError

from common.cli import CONF_DIR
from tests.helpers import compose_run

GROUPS = sorted(p.name for p in Path(CONF_DIR).iterdir() if p.is_dir() and p.name not in ("experiment",))


@pytest.mark.parametrize(
    "override", [f"{g}={f.stem}" for g in GROUPS for f in sorted(Path(CONF_DIR, g).glob("*.yaml"))]
)
def test_every_group_option_composes(override):
    run = compose_run([override])
    assert run.agent.name and run.scale.name and run.env.track


def test_root_defaults():
    run = compose_run()
    assert (run.agent.name, run.scale.name, run.transport.backend) == ("gvf_ddpg", "small_sn", "zenoh")
    assert run.actor.ou_speed_sigma == 0.4 and compose_run(["scale=small"]).actor.ou_speed_sigma is None
    assert run.agent.gammas == [0.0, 0.5, 0.9, 0.95, 0.97]


def test_the_small_scale_trains_with_lever_g_and_the_paper_scale_keeps_the_papers_ddpg():
    small = compose_run()
    s = small.scale
    assert (s.mirror_actor, s.crash_penalty, s.crash_memory, s.td3_actor_delay, s.td3_target_min_weight) == (
        True,
        300.0,
        3000,
        4,
        0.5,
    )
    assert small.env.gust_rate == 0.02 and compose_run(["env=lanedrive_procedural"]).env.gust_rate == 0.02
    paper = compose_run(["scale=paper"]).scale
    assert not paper.td3 and not paper.mirror_actor and paper.crash_penalty == 0.0 and paper.crash_memory == 0
    assert compose_run(["env=torcs"]).env.gust_rate == 0.0  # TORCS refuses gusts


LEVER_SI_OSG = (
    "actor_speed_init",
    "actor_offset_weight",
    "actor_offset_gammas",
    "actor_offset_after",
    "actor_offset_guard",
)


def test_the_small_scale_is_lever_g_small_g_names_it_and_small_sig_starts_slow_and_pulls_the_steering():
    small, small_g, sig = (compose_run([f"scale={name}"]).scale for name in ("small", "small_g", "small_sig"))
    assert [getattr(small, k) for k in LEVER_SI_OSG] == [0.0, 0.0, None, 0, False]
    assert {k for k in vars(small) if getattr(small, k) != getattr(small_g, k)} == {"name"}
    assert [getattr(sig, k) for k in LEVER_SI_OSG] == [-0.8, 100.0, None, 5000, True]
    differ = {k for k in vars(small) if getattr(small, k) != getattr(sig, k)}
    assert differ == {"name", "actor_speed_init", "actor_offset_weight", "actor_offset_after", "actor_offset_guard"}
    paper = compose_run(["scale=paper"]).scale
    assert (paper.actor_speed_init, paper.actor_offset_weight) == (0.0, 0.0)  # the paper's init, no pull


def test_small_sn_is_small_sig_with_the_target_speeds_noise_widened_and_a_user_value_wins():
    sig, sn = (compose_run([f"scale={name}"]) for name in ("small_sig", "small_sn"))
    assert {k for k in vars(sig.scale) if getattr(sig.scale, k) != getattr(sn.scale, k)} == {"name"}
    assert {k for k in vars(sig.actor) if getattr(sig.actor, k) != getattr(sn.actor, k)} == {"ou_speed_sigma"}
    assert (sig.actor.ou_speed_sigma, sn.actor.ou_speed_sigma) == (None, 0.4)
    assert compose_run(["scale=small_sn", "actor.ou_speed_sigma=0.2"]).actor.ou_speed_sigma == 0.2
    assert compose_run(["scale=paper"]).actor.ou_speed_sigma is None  # the other scales keep the paper's noise
    assert compose_run(["actor.ou_speed_sigma=0.2"]).actor.ou_speed_sigma == 0.2  # also over the root default


@pytest.mark.parametrize(
    "override, field",
    [("actor.num_envs=many", "num_envs"), ("env.lane_widht=3", "lane_widht"), ("env.direction=up", "direction")],
)
def test_bad_values_are_refused_naming_the_field(override, field):
    with pytest.raises((ConfigCompositionException, ValidationError, ValueError), match=field):
        compose_run([override])


@pytest.mark.parametrize(
    "override, field",
    [
        ("agent.gvf_terminal=bounce", "gvf_terminal"),
        ("scale.reward_scale=0", "reward_scale"),
        ("scale.crash_penalty=-1", "crash_penalty"),
        ("agent.rho_refresh_every=-1", "rho_refresh_every"),
        ("scale.crash_memory=-5", "crash_memory"),
        ("scale.lr_actor_decay_updates=-1", "lr_actor_decay_updates"),
        ("scale.lr_actor_decay_after=-1 scale.lr_actor_decay_updates=5", "lr_actor_decay_after"),
        ("scale.lr_actor_decay_after=100", "lr_actor_decay_after"),
        ("scale.lr_actor_final=0", "lr_actor_final"),
        ("scale.crash_steps=0", "crash_steps"),
        ("scale.crash_memory=0 scale.crash_memory_actor=false", "crash_memory_actor"),
        ("scale=paper scale.actor_min_q=true", "actor_min_q"),
        ("learner.rho_at=router", "rho_at"),
        ("learner.weights_dtype=int8", "weights_dtype"),
        ("learner.inbox_wait_s=5.0", "inbox_wait_s"),
        ("learner.inbox_wait_s=-1", "inbox_wait_s"),
        ("agent=ddpg_image learner.rho_at=actor", "rho_at"),
        ("actor.ou_theta=150", "ou_theta"),
        ("actor.ou_dt=0", "ou_dt"),
        ("actor.ou_sigma=-0.1", "ou_sigma"),
        ("actor.ou_steer_theta=101", "ou_steer_theta"),
        ("actor.ou_steer_sigma=-1", "ou_steer_sigma"),
        ("actor.ou_speed_theta=0", "ou_speed_theta"),
        ("actor.ou_speed_sigma=-0.5", "ou_speed_sigma"),
        ("scale.steer_increment=-0.1", "steer_increment"),
        ("scale.offset_weight=0.5", "offset_weight"),
        ("scale.n_step=3 scale.offset_weight=2", "offset_weight"),
        ("scale.steer_increment=3", "steer_increment"),
    ],
)
def test_bad_learning_values_are_refused_naming_the_field(override, field):
    with pytest.raises(ValueError, match=field):
        compose_run(override.split())


def finish(cmd: list[str], updates: int) -> None:
    """What a gvf-train run leaves that the study reads: its progress at the end."""
    import json

    run_dir = Path(next(c for c in cmd if c.startswith("hydra.run.dir=")).split("=", 1)[1])
    (run_dir / "progress.json").write_text(json.dumps({"updates": updates}))


def test_a_study_job_stopped_before_its_budget_writes_no_summary_so_a_rerun_runs_it(tmp_path, monkeypatch):
    from actors.evaluation import study

    monkeypatch.setattr(study.subprocess, "run", lambda cmd, **kw: finish(cmd, 900))  # stopped by a SIGTERM: rc 0
    with pytest.raises(RuntimeError, match="900 updates"):
        study.run_job("gvf_ddpg", 1, 55, 500, tmp_path / "runs", tmp_path / "work", [], updates=17500)
    assert not study.summary_path(tmp_path / "runs", "gvf_ddpg", 1).exists()
    with pytest.raises(RuntimeError, match="stopped early"):  # a wall-clock budget: 15 min not spent
        study.run_job("gvf_ddpg", 2, 15, 500, tmp_path / "runs", tmp_path / "work", [])


def test_a_study_job_whose_summary_exists_is_skipped(tmp_path, monkeypatch):
    from actors.evaluation import study

    done = study.summary_path(tmp_path / "runs", "ddpg_image", 3)
    done.parent.mkdir(parents=True)
    done.write_text("{}")
    ran = []
    monkeypatch.setattr(study.subprocess, "run", lambda cmd, **kw: ran.append(cmd))
    assert study.run_job("ddpg_image", 3, 15, 500, tmp_path / "runs", tmp_path / "work", []) == done
    assert ran == [] and not (tmp_path / "work").exists()


def test_a_study_job_with_an_update_budget_ends_the_run_there_and_records_it(tmp_path, monkeypatch):
    import json

    from actors.evaluation import study

    ran = []
    monkeypatch.setattr(
        study.subprocess, "run", lambda cmd, **kw: ran.append((cmd, kw["timeout"])) or finish(cmd, 17800)
    )
    mine = "scale.crash_penalty=150"
    path = study.run_job("gvf_ddpg", 1, 70, 500, tmp_path / "runs", tmp_path / "work", [mine], updates=17800)
    (cmd, timeout), record = ran[0], json.loads(path.read_text())
    assert "learner.max_updates=17800" in cmd and "max_seconds=4200" in cmd and timeout > 4200
    assert cmd.index("learner.max_updates=17800") < cmd.index(mine)  # an explicit override still wins
    assert record["updates_budget"] == 17800 and record["minutes"] == 70 and record["evaluations"] == []
    assert record["scale"] == "small_sn"  # the recipe it trained at, resolved as gvf-train composes it


def test_a_resumed_study_refuses_a_job_at_another_recipe_than_its_summary_and_a_bad_override(tmp_path, monkeypatch):
    import json

    from actors.evaluation import study

    done = study.summary_path(tmp_path / "runs", "gvf_ddpg", 0)
    done.parent.mkdir(parents=True)
    done.write_text(json.dumps({"scale": "small_g"}))
    ran = []
    monkeypatch.setattr(study.subprocess, "run", lambda cmd, **kw: ran.append(cmd))
    with pytest.raises(RuntimeError, match="small_g, this job at small_sn: give the study another --out"):
        study.run_job("gvf_ddpg", 0, 15, 500, tmp_path / "runs", tmp_path / "work", ["scale=small_sn"])
    assert study.run_job("gvf_ddpg", 0, 15, 500, tmp_path / "runs", tmp_path / "work", ["scale=small_g"]) == done
    from hydra.errors import ConfigCompositionException

    with pytest.raises(ConfigCompositionException, match="no_such_field"):  # refused before a run is started
        study.run_job("gvf_ddpg", 1, 15, 500, tmp_path / "runs", tmp_path / "work", ["scale.no_such_field=1"])
    assert ran == []


def test_a_rerun_study_job_moves_an_interrupted_attempt_aside_instead_of_mixing_it_in(tmp_path, monkeypatch):
    import json

    from actors.evaluation import study

    stale = tmp_path / "work" / "gvf_ddpg-seed2"
    stale.mkdir(parents=True)
    (stale / "eval.jsonl").write_text(json.dumps({"updates": 500, "mean": {}, "drives": []}) + "\n")
    monkeypatch.setattr(study.subprocess, "run", lambda cmd, **kw: finish(cmd, 100))
    path = study.run_job("gvf_ddpg", 2, 15, 500, tmp_path / "runs", tmp_path / "work", [], updates=100)
    record = json.loads(path.read_text())
    (aside,) = (tmp_path / "work").glob("gvf_ddpg-seed2.interrupted-*")
    assert record["evaluations"] == [] and (aside / "eval.jsonl").exists()  # nothing of the old attempt lost


def test_a_run_made_outside_the_study_is_adopted_with_minutes_from_its_start(tmp_path):
    import json
    import os

    from actors.evaluation import study

    run = tmp_path / "run"
    (run / ".hydra").mkdir(parents=True)
    (run / ".hydra" / "config.yaml").write_text("seed: 3\n")
    os.utime(run / ".hydra" / "config.yaml", (1000.0, 1000.0))
    drive = {"track": "dune", "lap_completed": 1.0, "episode_length": 700}
    e = {"updates": 500, "time": 1090.0, "mean": {"lap_completed": 1.0}, "drives": [drive]}
    (run / "eval.jsonl").write_text(json.dumps(e) + "\n")
    path = study.adopt(run, "gvf_ddpg", 3, 15, 500, tmp_path / "runs", ["agent.gvf_terminal=zero"])
    record = json.loads(path.read_text())
    assert path == study.summary_path(tmp_path / "runs", "gvf_ddpg", 3)
    assert record["evaluations"][0]["minute"] == 1.5 and record["adopted_from"] == str(run)
    assert record["overrides"] == ["agent.gvf_terminal=zero"] and record["last"] is None  # no checkpoint there


def test_step_sizes_come_from_the_scale_unless_the_agent_sets_them():
    from common.config.agent import step_sizes

    paper = compose_run(["scale=paper"])
    assert step_sizes(paper.agent, paper.scale) == {
        "discount": 0.99,
        "target_update": 0.001,
        "lr_actor": 1e-6,
        "lr_critic": 1e-4,
        "lr_gvf": 1e-4,
        "lr_behaviour": 1e-4,
    }
    small = compose_run(["scale=small"])
    assert step_sizes(small.agent, small.scale)["lr_actor"] == small.scale.lr_actor != 1e-6
    mine = compose_run(["scale=small", "agent.lr_actor=0.5"])
    assert step_sizes(mine.agent, mine.scale)["lr_actor"] == 0.5
    assert step_sizes(mine.agent, mine.scale)["lr_critic"] == small.scale.lr_critic


def test_the_shaped_reward_charges_the_crash_once_and_scales_numpy_and_torch_alike():
    import numpy as np
    import torch

    from common.config.agent import shaped_reward

    scale = compose_run(["scale=small", "scale.crash_penalty=10", "scale.reward_scale=0.1"]).scale
    reward, terminated, offset = [1.0, 2.0, 3.0], [0.0, 0.0, 1.0], [0.5, 0.0, 0.0]
    expected = [0.1, 0.2, -0.7]  # (3 - 10) * 0.1 on the step that left the lane only
    assert np.allclose(shaped_reward(np.array(reward), np.array(terminated), np.array(offset), scale), expected)
    as_tensors = [torch.tensor(x) for x in (reward, terminated, offset)]
    assert torch.allclose(shaped_reward(*as_tensors, scale), torch.tensor(expected))
    halved = shaped_reward(np.array(reward), np.array(terminated), np.array(offset), scale, penalty_weight=0.5)
    assert np.allclose(halved, [0.1, 0.2, -0.2])  # an n-step window's penalty, discounted
    weighted = compose_run(
        ["scale=small", "scale.crash_penalty=10", "scale.reward_scale=0.1", "scale.offset_weight=3"]
    ).scale
    charged = shaped_reward(np.array(reward), np.array(terminated), np.array(offset), weighted)
    assert np.allclose(charged, [0.0, 0.2, -0.7])  # (1 - 2 * 0.5) * 0.1: the offset charged twice more


def test_actor_squash_comes_from_the_scale_unless_the_agent_sets_it():
    from common.config.agent import actor_squash
    from common.networks import make_policy

    paper = compose_run(["scale=paper"])
    assert actor_squash(paper.agent, paper.scale) == "clip"  # the paper's linear output and clip
    mine = compose_run(["scale=paper", "agent.actor_squash=tanh"])
    assert actor_squash(mine.agent, mine.scale) == "tanh"
    assert make_policy(mine.agent, mine.scale).actor.squash == "tanh"


@pytest.mark.parametrize(
    "override, field",
    [("agent.actor_squash=sigmoid", "agent.actor_squash"), ("scale.actor_squash=relu", "scale.actor_squash")],
)
def test_a_bad_actor_squash_is_refused_naming_the_field(override, field):
    with pytest.raises(ValueError, match=field):
        compose_run([override])
