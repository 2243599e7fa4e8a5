"""The offline path end to end, tiny: collect, gvf-offline (GVF-BCQ and E2E-BCQ, as processes),
gvf-eval's loader on its checkpoints, the Jackal-layout comparison with MPC and the kinematic
controller, and the study's tables and figure rebuilt from its summaries alone."""

from __future__ import annotations

import json

from actors.collect import collect_worker
from actors.evaluation import offline_study
from actors.evaluation.policies import checkpoint_policy
from common import checkpoint

TINY_OFFLINE = [
    "scale.conv_channels=[4,8,8,8,8]",
    "scale.gvf_hidden=[32,32]",
    "scale.behaviour_hidden=[32,16]",
    "scale.batch_size=16",
    "agent.behaviour_warmup_updates=5",
    "agent.metrics_every=10",
    "learner.torch_threads=1",
    "offline.start=100",
    "offline.gvf_updates=20",
    "offline.bcq_updates=20",
]


def test_collect_train_offline_and_compare(tmp_path, capsys):
    data, out, work = tmp_path / "data", tmp_path / "summaries", tmp_path / "work"
    collect_worker(str(data), seed=0, worker=0, quota=300, cars=2, shard_size=100, env_kwargs={"track": "train"})
    args = ["--data", str(data), "--seeds", "0", "--out", str(out), "--work", str(work), "--tracks", "dune"]
    offline_study.main([*args, "--", *TINY_OFFLINE])

    gvf_run = work / "gvf_bcq-seed0"
    records = [json.loads(line) for line in (gvf_run / "offline_metrics.jsonl").read_text().splitlines()]
    assert [r["phase"] for r in records] == ["gvf", "gvf", "bcq", "bcq"]
    assert records[0]["train/rho_bar"] > 0 and "losses/td" in records[0] and "losses/loss_qvalue" in records[-1]
    assert records[-1]["update"] == 40  # BCQ's updates count on from Algorithm 2's
    assert (gvf_run / "checkpoints" / "offline" / "representation.pt").exists()
    for method, name, updates in (("gvf_bcq", "GVF-BCQ", 40), ("e2e_bcq", "E2E-BCQ", 40)):
        _, meta = checkpoint_policy(checkpoint.find(work / f"{method}-seed0" / "checkpoints" / "offline"))
        assert meta["agent"] == name and meta["updates"] == updates  # what gvf-eval loads

    summary = json.loads((out / "gvf_bcq" / "seed0.json").read_text())
    assert len(summary["drives"]) == 2 * 2 * 2  # target speeds x markings x directions
    assert summary["transitions"] == 300 and sum(summary["hist"]["alpha"]) > 0
    base = json.loads((out / "baselines.json").read_text())
    assert all(d["metrics"]["lap_completed"] == 1.0 for d in base["MPC"]["drives"])  # the MPC laps at both speeds
    text = (out / "comparison.md").read_text()
    for method in ("GVF-BCQ", "E2E-BCQ", "MPC", "kinematic"):
        assert f"| {method} | " in text
    assert "| E2E-BCQ | 1 | 0.4 m/s | damaged |" in text and "dune CCW" in text
    assert (out / "distributions.png").stat().st_size > 10_000 and (out / "algorithm2_curves.png").exists()
    assert [r["phase"] for r in summary["curves"]] == ["gvf", "gvf", "bcq", "bcq"]

    capsys.readouterr()
    offline_study.main([*args, "--", *TINY_OFFLINE])  # resumable: every job's summary exists
    assert capsys.readouterr().out.count("skip ") == 2
