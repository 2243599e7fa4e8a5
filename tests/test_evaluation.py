"""gvf-eval on the kinematic controller, and a short training run evaluated from its checkpoint."""

import json
import subprocess
import threading

import numpy as np
import pytest

from actors.evaluation.evaluate import evaluate
from actors.evaluation.policies import checkpoint_policy, kinematic_policy
from common.config.env import VehicleConfig
from common.launch import train
from common.selection import RANKING, better, selection_key
from tests.helpers import BIN, TINY, compose_run

FIGURES = ("lane_centeredness.png", "distributions.png")


def gvf_eval(*args, cwd):
    out = subprocess.run([str(BIN / "gvf-eval"), *args], capture_output=True, text=True, timeout=300, cwd=cwd)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def test_drives_run_together_give_what_each_gives_alone():
    together = evaluate(kinematic_policy(), tracks=["sage", "brook"])
    alone = [r for name in ("sage", "brook") for r in evaluate(kinematic_policy(), tracks=[name])]
    assert [(r["track"], r["direction"]) for r in together] == [
        ("sage", "ccw"),
        ("sage-r", "cw"),
        ("brook", "ccw"),
        ("brook-r", "cw"),
    ]
    for a, b in zip(together, alone):
        assert a["metrics"] == b["metrics"] and a["metrics"]["lap_completed"] == 1.0
        assert all(np.array_equal(a["trace"][k], b["trace"][k]) for k in a["trace"])
    assert len(together[0]["trace"]["alpha"]) != len(together[2]["trace"]["alpha"])  # laps of unequal length


def test_a_slower_control_rate_laps_and_counts_reward_per_second_at_its_own_rate():
    (drive,) = evaluate(
        kinematic_policy(VehicleConfig(dt=0.2)), tracks=["sage"], directions=("ccw",), vehicle={"dt": 0.2}
    )
    m = drive["metrics"]
    assert m["lap_completed"] == 1.0 and m["near_out_of_lane"] == 0.0
    assert m["reward_per_s"] == pytest.approx(5 * m["reward_per_step"])  # 5 steps per second, not 10


def test_the_best_evaluation_has_most_laps_then_least_near_out_then_least_abs_alpha_then_reward_per_second():
    def v(laps, near_out, reward, alpha=0.05):
        return {"lap_completed": laps, "near_out_of_lane": near_out, "reward_per_s": reward, "offcenteredness": alpha}

    assert better(v(0.0, 0.5, 1.0), None)
    assert better(v(0.5, 0.2, 1.0), v(0.25, 0.0, 9.0))  # laps first
    assert better(v(0.5, 0.01, 1.0), v(0.5, 0.02, 9.0))  # then the safer, though slower
    assert better(v(0.5, 0.0, 1.0, alpha=0.02), v(0.5, 0.0, 9.0, alpha=0.2))  # then the centred, though slower
    assert better(v(0.5, 0.01, 2.0), v(0.5, 0.01, 1.0))  # then reward per second
    assert not better(v(0.5, 0.01, 1.0), v(0.5, 0.01, 1.0))  # the first of equals is kept


def test_validation_selection_never_evaluates_a_test_road(monkeypatch):
    import pytest

    from actors.envs.tracks import track_names
    from actors.evaluation import periodic
    from common.config.run import RunConfig

    driven = []
    real = periodic.evaluate
    monkeypatch.setattr(
        periodic,
        "evaluate",
        lambda policy, *a, tracks=None, **kw: (driven.append(list(tracks)), real(policy, *a, tracks=tracks, **kw))[1],
    )
    cfg = RunConfig()
    cfg.eval.validation_tracks = cfg.eval.validation_tracks[:2]
    mean = periodic.validate(kinematic_policy(), cfg)
    assert driven == [["procedural:9001", "procedural:9002"]] and mean["lap_completed"] == 1.0
    for road in (track_names("test")[0], track_names("test")[1] + "-r", track_names("train")[0]):
        cfg.eval.validation_tracks = ["procedural:9001", road]
        with pytest.raises(ValueError, match="eval.validation_tracks"):
            periodic.validate(kinematic_policy(), cfg)
    assert len(driven) == 1  # refused before any drive


def test_kinematic_controller_laps_every_test_road_with_no_near_out_of_lane(tmp_path):
    stdout = gvf_eval("policy=kinematic", "eval.video=true", f"hydra.run.dir={tmp_path}", cwd=tmp_path)
    report = json.loads((tmp_path / "eval.json").read_text())
    assert len(report["drives"]) == 12  # 6 test roads x 2 directions
    assert all(
        d["metrics"]["lap_completed"] == 1.0 and d["metrics"]["near_out_of_lane"] == 0.0 for d in report["drives"]
    )
    assert "Near out of lane" in stdout and "| **mean** |" in (tmp_path / "eval.md").read_text()
    assert all((tmp_path / f).stat().st_size > 1000 for f in FIGURES)
    import imageio.v3 as iio

    video = iio.imread(tmp_path / "lap.gif")  # one lap of the first road: top-down | camera
    assert video.ndim == 4 and video.shape[0] > 50 and video.shape[1:] == (128, 256, 3)


def test_short_training_then_eval_and_comparison_of_its_checkpoint_write_tables_figures_and_curves(tmp_path):
    run_dir = tmp_path / "run"
    cfg = compose_run(
        [
            *TINY,
            "transport=inproc",
            "progress=false",
            "actors.count=1",
            "max_seconds=60",
            "learner.max_updates=40",
            "agent.metrics_every=10",
            "eval.every_updates=20",
            "eval.directions=[ccw]",
        ]
    )
    stop = threading.Event()
    train(cfg, str(run_dir), stop)
    lines = [json.loads(x) for x in (run_dir / "eval.jsonl").read_text().splitlines()]
    assert lines and lines[0]["updates"] >= 20 and len(lines[0]["drives"]) == 6  # periodic evaluation ran
    best = max(lines, key=lambda x: selection_key(x["validation"]))  # chosen on validation (first of equals)
    _, meta = checkpoint_policy(run_dir / "checkpoints" / "best-policy.pt")
    assert meta["updates"] == best["updates"] and meta["agent"] == "gvf_ddpg"  # the best evaluation's policy is kept
    out = tmp_path / "eval"
    gvf_eval(
        f"checkpoint={run_dir}/checkpoints",
        f"eval.runs={run_dir}",
        "eval.directions=[ccw]",
        f"hydra.run.dir={out}",
        cwd=tmp_path,
    )
    report = json.loads((out / "eval.json").read_text())
    assert report["title"].startswith("gvf_ddpg after") and len(report["drives"]) == 6
    assert "Reward /s" in (out / "eval.md").read_text()
    assert all((out / f).stat().st_size > 1000 for f in (*FIGURES, "learning_curves.png"))
    # the run's summary (as the study commits it), and the comparison built from summaries alone
    from actors.evaluation.compare import compare
    from actors.evaluation.study import summarize

    record = summarize(run_dir, start=lines[0]["time"] - 60, job={"variant": "gvf_ddpg", "seed": 0})
    assert [e["updates"] for e in record["evaluations"]] == [x["updates"] for x in lines]
    assert record["last"]["clean"]["mean"]["lap_completed"] >= 0 and len(record["last"]["damaged"]["drives"]) == 12
    assert record["selected"]["updates"] == best["updates"] and record["selected_by"] == RANKING
    assert record["learner"]["updates"] and len(record["learner"]["diag/dq_dsteer_abs"]) == len(
        record["learner"]["updates"]
    )
    (tmp_path / "runs" / "gvf_ddpg").mkdir(parents=True)
    (tmp_path / "runs" / "gvf_ddpg" / "seed0.json").write_text(json.dumps(record))
    table = compare(tmp_path / "runs", tmp_path / "results").read_text()
    assert table.count("### ") == 5 and "### last checkpoint, test roads, damaged lane markings\n" in table
    assert table.count("| gvf_ddpg | 1 |") == 4 and table.count("| kinematic controller | - |") == 4
    assert f"| gvf_ddpg | 0 | {record['progress']['updates']} |" in table  # the run's staying-good row, its updates
    for name in ("curve_reward_per_s", "curve_episode_length", "curve_offcenteredness", "lane_centeredness_final"):
        assert (tmp_path / "results" / f"{name}.png").stat().st_size > 1000


def test_staying_good_row_counts_from_the_first_all_lap_evaluation_and_shows_its_updates():
    from actors.evaluation.compare import staying_good_table

    def evaluation(updates, laps):
        drives = [{"lap_completed": float(i < laps)} for i in range(12)]
        return {"updates": updates, "minute": updates / 1000, "mean": {"lap_completed": laps / 12}, "drives": drives}

    last = {
        "mean": {
            "lap_completed": 11 / 12,
            "near_out_of_lane": 0.004,
            "offcenteredness": 0.05,
            "jerkiness_angular": 1.38,
        }
    }
    record = {
        "seed": 4,
        "progress": {"updates": 2000},
        "evaluations": [evaluation(500, 3), evaluation(1000, 12), evaluation(1500, 11), evaluation(2000, 5)],
        "last": {"clean": {**last, "drives": [{}] * 12}},
    }
    row = staying_good_table({"gvf_ddpg": [record]})[2]
    # minute 1.0 and 1,000 updates to all 12; 1 of the 2 later evaluations lapped >= 11; no selected policy
    assert row == "| gvf_ddpg | 4 | 2000 | 1.0 | 1000 | 11 | 0.004 | 0.050 | 1.380 | 2 | 0.50 | - |"


def test_equal_updates_cuts_every_run_at_the_same_update_count():
    from actors.evaluation.equal_updates import at_cut

    def run(laps_per_eval):
        drives = [{"track": f"t{i}"} for i in range(12)]
        evals = [
            {"updates": 500 * (i + 1), "minute": 0.5 * (i + 1), "mean": {"lap_completed": x / 12}, "drives": drives}
            for i, x in enumerate(laps_per_eval)
        ]
        return {"seed": 0, "evaluations": evals, "last": {"clean": {"mean": {"lap_completed": 1.0}, "drives": drives}}}

    fast = run([0, 12, 12, 3, 12, 12, 12, 12])  # the cut at 2,500 keeps 0 12 12 3 12
    slow = run([0, 0, 0, 0, 0, 12, 12, 12])  # nothing lapped by 2,500
    a = at_cut([fast, slow], 2500)
    assert a["last_laps"] == [12, 0] and a["later"] == 3 and a["later_with_11"] == 2
    assert abs(a["last3_fraction"] - np.mean([(12 + 3 + 12) / 36, 0.0])) < 1e-9
    later = at_cut([fast, slow], 4000)  # after the first all-12: fast 12 3 12 12 12 12, slow 12 12
    assert (later["later"], later["later_with_11"]) == (8, 7)


def test_speed_tradeoff_measures_each_speed_and_finds_what_the_discount_pays_for():
    from actors.evaluation.speed_tradeoff import bins, preferred

    def evaluation(speed, reward, failed):
        drives = [{"lap_completed": 0.0 if i < failed else 1.0, "episode_length": 500} for i in range(12)]
        mean = {"lap_completed": (12 - failed) / 12, "average_speed": speed, "reward_per_step": reward}
        return {"updates": 500, "minute": 1.0, "mean": mean, "drives": drives}

    before = [evaluation(15.2, 0.7, 6)]  # before the first all-lap evaluation: not counted
    later = [evaluation(10.2, 0.5, 0), evaluation(13.2, 0.65, 3)] * 4 + [evaluation(10.3, 0.5, 0)]
    per_bin = bins([{"seed": 0, "evaluations": [*before, evaluation(10.1, 0.5, 0), *later], "last": None}])
    assert sorted(per_bin) == [10.0, 13.0]
    slow, fast = per_bin[10.0], per_bin[13.0]
    assert (slow["evaluations"], slow["with_11"], slow["p"]) == (5, 5, 0.0)
    assert (fast["evaluations"], fast["with_11"], fast["failures"]) == (4, 0, 12) and fast["p"] == 12 / 24000
    assert abs(fast["r"] - 0.65) < 1e-12
    # the paper's discount pays for the speed that loses 3 laps of 12; a longer one or a crash penalty does not
    assert preferred(per_bin, 0.99, min_evaluations=1) == 13.0
    assert preferred(per_bin, 0.999, min_evaluations=1) == 10.0
    assert preferred(per_bin, 0.99, penalty=300, min_evaluations=1) == 10.0
    assert preferred(per_bin, 0.99, min_evaluations=5) == 10.0  # the fast bin holds too few evaluations
