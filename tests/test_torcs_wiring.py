"""`env=torcs` end to end (issue 15, stage 6): the config, the actor's TORCS vector env with priority
track sampling over roads.json's train roads less its validation roads, TORCS road names on the wire
and in the learner's track table, gvf-eval and the periodic evaluator's validation on TORCS roads.

The config, road-split and wire tests run everywhere; the rest drive the real TORCS and skip until
`make torcs` has built it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from actors.envs.simulators import known_roads, road_names
from actors.envs.torcs.protocol import find_install
from actors.envs.torcs.roads import load_road_set
from actors.envs.torcs.roads import road_names as torcs_roads
from actors.evaluation import periodic
from common import checkpoint, wire
from common.wire_rules import check_tracks
from tests.helpers import compose_run, run_inproc

needs_torcs = pytest.mark.skipif(find_install() is None, reason="TORCS is not built: run `make torcs`")
SHORT_TEST_ROAD = "a-speedway"  # 1.9 km: a kinematic lap is about 1,000 steps

# -- everywhere --------------------------------------------------------------------------------------


def test_env_torcs_composes_without_the_build():
    cfg = compose_run(["env=torcs"])
    assert cfg.env.id == "TorcsDrive-v0" and cfg.env.track == "train"


@pytest.mark.parametrize(
    "overrides, field",
    [(["env.id=CarRacing-v3"], "env.id"), (["env=torcs", "env.track=procedural"], "env.track")],
)
def test_a_bad_simulator_is_refused_naming_the_field(overrides, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        compose_run(overrides)


def test_torcs_sampling_draws_train_roads_less_the_validation_roads():
    env = compose_run(["env=torcs"]).env
    train, validation = road_names(env, "train"), torcs_roads("validation")
    assert validation and set(validation) <= set(load_road_set()["train"])  # held out of train, never test
    assert not set(validation) & set(train) and not set(validation) & set(road_names(env, "all"))
    assert set(train) | set(validation) == set(load_road_set()["train"])
    assert road_names(env, "test") == ["dirt-4", "spring", "alpine-2", "wheel-2", "a-speedway"]
    assert periodic.validation_roads(compose_run(["env=torcs"])) == validation


def test_torcs_road_names_pass_the_wire_and_the_actors_track_check():
    table = wire.TrackTable(3, {"dirt-4": 120, "e-track-2": 40, "alpine-1": 0})
    back = wire.decode(wire.encode(table))
    assert back.steps == table.steps
    check_tracks(back, known_roads(compose_run(["env=torcs"]).env))  # raises on an unknown road
    summary = wire.EpisodeSummary("actor-0", 0, 0, "e-track-2", 57, 1.5, 3)
    assert wire.decode(wire.encode(summary)).track == "e-track-2"
    with pytest.raises(wire.WireError):  # a LaneDrive actor does not take a TORCS table, nor the reverse
        check_tracks(back, known_roads(compose_run([]).env))


# -- the real TORCS (after `make torcs`) ----------------------------------------------------------------


@needs_torcs
def test_the_actors_env_is_torcs_with_priority_track_sampling():
    from actors.actor import make_env
    from actors.envs.torcs.env import TorcsDriveVectorEnv
    from actors.track_sampling import PriorityTrackSampler

    cfg = compose_run(["env=torcs", "env.max_steps=3", "actor.num_envs=1"])
    sampler = PriorityTrackSampler(road_names(cfg.env, "train"), np.random.default_rng(0))
    env = make_env(cfg, sampler)
    try:
        assert isinstance(env, TorcsDriveVectorEnv)
        _, info = env.reset(seed=0)
        first = str(info["track"][0])
        assert first in sampler.names
        for _ in range(3):
            _, _, term, trunc, info = env.step(np.zeros((1, 2), np.float32))
        assert trunc[0] and sampler.table()[first] == 3  # recorded before the next road was drawn
        assert str(info["track"][0]) in sampler.names
    finally:
        env.close()


@needs_torcs
def test_gvf_eval_env_torcs_laps_a_test_road_with_the_kinematic_controller(tmp_path, monkeypatch):
    from actors.evaluation import evaluate, main

    monkeypatch.setattr(evaluate, "road_names", lambda env, split: [SHORT_TEST_ROAD])  # one road, not all five
    cfg = compose_run(["env=torcs", "policy=kinematic", f"eval.out_dir={tmp_path}"])
    main.run_eval(cfg, tmp_path)
    report = json.loads((tmp_path / "eval.json").read_text())
    (drive,) = report["drives"]
    assert drive["track"] == SHORT_TEST_ROAD and drive["direction"] == "forward"
    assert drive["metrics"]["lap_completed"] == 1.0 and drive["metrics"]["average_speed"] > 10


@needs_torcs
def test_the_periodic_evaluator_validates_on_the_torcs_validation_roads():
    from actors.envs.simulators import vehicle
    from actors.evaluation.policies import kinematic_policy

    cfg = compose_run(["env=torcs"])
    mean = periodic.validate(kinematic_policy(vehicle(cfg.env)), cfg)
    assert mean["lap_completed"] == 1.0  # the kinematic controller laps dirt-3, g-track-1 and michigan


@needs_torcs
@pytest.mark.slow
def test_gvf_train_env_torcs_inproc_reaches_learner_updates(tmp_path):
    result, ended = run_inproc(["env=torcs", "learner.max_updates=10"], tmp_path, watchdog_s=240)
    assert ended and result["updates"] >= 10 and result["rejected"] == 0
    tracks = checkpoint.load(checkpoint.latest(tmp_path / "checkpoints"))["tracks"]
    assert tracks and set(tracks) <= set(road_names(compose_run(["env=torcs"]).env, "train"))
