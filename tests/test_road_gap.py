"""road_gap: each checkpoint's laps, speed and per-step crash probability on train, test and validation roads."""

import json

import numpy as np

from actors.evaluation.policies import kinematic_policy
from actors.evaluation.road_gap import drive_splits, measure_all, newest, report


def test_each_set_of_roads_counts_its_laps_speed_and_crashes_per_step():
    kinematic = kinematic_policy()

    def half_crashing(obs, info):  # the controller, but the second car of every batch steers full left
        actions = np.array(kinematic(obs, info), np.float32)
        actions[1::2, 0] = 1.0
        return actions

    by_split = {"train": ["sage"], "test": ["brook"], "validation": ["procedural:9001"]}
    clean = drive_splits(kinematic, by_split=by_split)
    assert [clean[s]["laps"] for s in by_split] == [2, 2, 2] and all(clean[s]["p"] == 0.0 for s in by_split)
    assert all(8.0 < clean[s]["speed"] < 21.0 for s in by_split)
    assert all(0.0 < clean[s]["offcentre"] < 0.1 for s in by_split)  # the controller drives the centre
    crashing = drive_splits(half_crashing, by_split=by_split)
    for s in by_split:  # the full-lock car leaves the road within seconds: one failure in its few steps
        m = crashing[s]
        assert (m["drives"], m["laps"]) == (2, 1)
        assert m["steps"] < clean[s]["steps"] and m["p"] == 1 / m["steps"]
    table = "\n".join(report({"ckpt-a": {"updates": 5, **crashing}, "ckpt-b": {"updates": 9, **clean}}))
    assert "| ckpt-a | 5 | 1/2 |" in table and "| ckpt-b | 9 | 2/2 |" in table
    assert "Pooled over the 2 checkpoints failing the test roads (< 11 laps)" in table  # 1 and 2 laps of 2
    assert f"| {clean['test']['offcentre']:.3f} | {clean['train']['offcentre']:.3f} |" in table
    older = {k: {f: v for f, v in m.items() if f != "offcentre"} for k, m in clean.items()}  # a cache before it
    assert report({"ckpt-c": {"updates": 1, **older}})[2].endswith("| - | - |")


def test_a_second_pass_drives_only_the_checkpoints_not_yet_in_the_cache(tmp_path):
    for run in ("a", "b"):
        (tmp_path / run / "checkpoints").mkdir(parents=True)
        for updates in (500, 1000, 12000):
            (tmp_path / run / "checkpoints" / f"ckpt-{updates:09d}.pt").write_bytes(b"")
    assert [p.name for p in newest([tmp_path], last=2)] == ["ckpt-000001000.pt", "ckpt-000012000.pt"] * 2
    driven = []

    def measure(path):
        driven.append(path.name)
        return {"updates": int(path.stem.split("-")[1])}

    cache = tmp_path / "gap.json"
    first = measure_all(newest([tmp_path / "a"], last=1), cache, measure)
    assert driven == ["ckpt-000012000.pt"] and list(first.values()) == [{"updates": 12000}]
    both = measure_all(newest([tmp_path], last=1), cache, measure)
    assert driven == ["ckpt-000012000.pt"] * 2 and len(both) == 2  # run a's came from the cache
    assert set(json.loads(cache.read_text())) == set(both)
