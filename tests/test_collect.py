"""gvf-collect (actors.collect): the random-walk collector's dataset is a consistent record of its drives."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from actors.collect import collect_worker
from common.dataset import Dataset, DatasetError

ENV = {"track": "train", "direction": "random", "random_start": True, "max_steps": 40}


def _episodes(ds: Dataset) -> dict[int, dict[str, torch.Tensor]]:
    cols = {}
    for td, tracks in ds:
        for k in td.keys():
            cols.setdefault(k, []).append(torch.as_tensor(td[k]).clone())
        cols.setdefault("track_name", []).append(np.array(tracks)[td["track"].reshape(-1).numpy()])
    cols = {k: (np.concatenate(v) if k == "track_name" else torch.cat(v)) for k, v in cols.items()}
    out = {}
    for e in torch.unique(cols["episode"]).tolist():
        rows = torch.nonzero(cols["episode"].reshape(-1) == e).reshape(-1)
        rows = rows[torch.argsort(cols["step"].reshape(-1)[rows])]
        out[e] = {k: v[rows.numpy()] if k == "track_name" else v[rows] for k, v in cols.items()}
    return out


def test_the_collectors_dataset_chains_each_episode_step_by_step(tmp_path):
    written = collect_worker(str(tmp_path), seed=1, worker=0, quota=240, cars=2, shard_size=100, env_kwargs=ENV)
    ds = Dataset.open(tmp_path)
    assert written == len(ds) == 240 and len(ds.shards) == 3
    episodes = _episodes(ds)
    assert len(episodes) >= 6  # 2 cars, 120 steps each, episodes of at most 40 steps
    ended = 0
    for ep in episodes.values():
        n = len(ep["step"])
        assert torch.equal(ep["step"].reshape(-1), torch.arange(n, dtype=torch.int32))
        assert len(set(ep["track_name"].tolist())) == 1
        # s_{t+1} of one row is s_t of the next: frames, speed, lane state, last action
        assert torch.equal(ep["next_frame"][:-1, 0], ep["image"][1:, 0])
        assert torch.equal(ep["image"][:-1, 0], ep["image"][1:, 1])
        assert torch.equal(ep["action"][:-1], ep["last_action"][1:])
        assert torch.allclose(ep["next_speed"][:-1], ep["speed"][1:])
        assert torch.allclose(ep["next_alpha"][:-1], ep["alpha"][1:])
        done = (ep["terminated"] | ep["truncated"]).reshape(-1)
        assert not done[:-1].any()
        ended += int(done[-1])
        assert not bool(ep["terminated"].any()) or float(ep["next_alpha"][-1].abs()) > 1.0
        if bool(ep["truncated"][-1]):
            assert n == ENV["max_steps"]
    assert ended >= 4
    actions = torch.cat([ep["action"] for ep in episodes.values()])
    assert actions.abs().max() <= 1.0 and actions[:, 0].std() > 0.01 and actions[:, 1].std() > 0.01
    assert torch.isnan(torch.cat([ep["log_mu"] for ep in episodes.values()])).all()  # the controller's mu is unknown


def test_gvf_collect_runs_workers_into_one_dataset_and_refuses_a_repeated_seed(tmp_path):
    out = tmp_path / "ds"
    args = [sys.executable, "-m", "actors.collect", f"collect.out={out}", "collect.transitions=150"]
    args += ["collect.workers=2", "collect.cars=2", "collect.shard_size=50", "progress=false", "seed=5"]
    args += [f"hydra.run.dir={tmp_path / 'hydra'}"]
    done = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "collected 150 transitions" in done.stdout
    ds = Dataset.open(out)
    assert len(ds) == 150 and {s["name"].split("-")[1] for s in ds.shards} == {"s5w0", "s5w1"}
    assert ds.meta["env"]["gust_rate"] == 0.0  # the training env gusts (lever G); the random walk drives without
    again = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert again.returncode != 0 and "already holds data collected with seed=5" in again.stderr
    assert len(Dataset.open(out)) == 150


def test_a_bad_collect_value_is_refused_naming_the_field():
    from common.cli import compose_run

    with pytest.raises(ValueError, match="collect.split"):
        compose_run(["collect.split=holdout"])
    with pytest.raises((ValueError, DatasetError), match="offline.method"):
        compose_run(["offline.method=cql"])
    with pytest.raises(ValueError, match="offline.mirror"):
        compose_run(["offline.mirror=1.5"])


def test_action_noise_is_a_truncated_normal_whose_density_is_stored(tmp_path):
    from actors.collect import truncated_normal

    rng = np.random.default_rng(0)
    samples = truncated_normal(rng, np.zeros(20_000), 0.15)
    assert abs(samples.std() - 0.15) < 0.005 and abs(samples.mean()) < 0.005
    edge = truncated_normal(rng, np.full(20_000, 0.95), 0.15)
    assert edge.max() <= 1.0 and edge.mean() < 0.95  # cut at the box's edge, not piled on it
    collect_worker(str(tmp_path), seed=1, worker=0, quota=60, cars=2, shard_size=100, env_kwargs=ENV, action_noise=0.15)
    td, _ = Dataset.open(tmp_path).shard(0)
    log_mu = torch.as_tensor(td["log_mu"])
    # a known density: finite, at most the peak of two normals of std 0.15 each cut to half its mass
    peak = 2 * (-np.log(0.15 * np.sqrt(2 * np.pi)) + np.log(2.0))
    assert torch.isfinite(log_mu).all() and float(log_mu.max()) <= peak
    assert torch.as_tensor(td["action"]).abs().max() <= 1.0
