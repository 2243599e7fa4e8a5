"""The creep census over study summaries (actors.evaluation.creep_census)."""

import json

from actors.evaluation.creep_census import census


def write(path, variant, seed, speeds_laps):
    evals = [
        {"updates": 500 * (i + 1), "mean": {"average_speed": v, "lap_completed": laps / 12}}
        for i, (v, laps) in enumerate(speeds_laps)
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"variant": variant, "seed": seed, "evaluations": evals}))


def test_runs_are_counted_per_seed_by_their_early_speed(tmp_path):
    fast, slow = (15.5, 0), (12.0, 0)
    write(tmp_path / "a" / "gvf_ddpg" / "seed0.json", "gvf_ddpg", 0, [slow] * 3 + [fast] * 4 + [(10.0, 12)])
    write(tmp_path / "b" / "gvf_ddpg" / "seed0.json", "gvf_ddpg", 0, [slow] * 8)
    write(tmp_path / "b" / "gvf_ddpg" / "seed1.json", "gvf_ddpg", 1, [slow] * 3 + [fast] * 5)
    write(tmp_path / "b" / "ddpg_image" / "seed1.json", "ddpg_image", 1, [fast] * 8)  # another variant
    write(tmp_path / "c" / "gvf_ddpg" / "seed2.json", "gvf_ddpg", 2, [fast] * 2)  # no evaluation in the window
    (tmp_path / "c" / "gvf_ddpg" / "seed3.json").write_text("{not json")  # unreadable: passed over

    result = census([tmp_path], "gvf_ddpg", speed=14.8, window=(2000, 3500))

    assert result["runs"] == 3 and result["crept"] == 2 and result["crept_then_lapped"] == 1
    assert result["per_seed"] == {
        "0": {"runs": 2, "crept": 1, "crept_then_lapped": 1, "lapped_by": 1},  # its all 12 came at 4,000
        "1": {"runs": 1, "crept": 1, "crept_then_lapped": 0, "lapped_by": 0},
    }
    assert result["by"] == 5000 and result["lapped_by"] == 1
    assert census([tmp_path], "gvf_ddpg", 14.8, (2000, 3500), by=3500)["lapped_by"] == 0
    assert result["seeds_with_both"] == 1 and result["seeds_with_2_or_more_runs"] == 1
