"""The offline path end to end, tiny: collect, gvf-offline (GVF-BCQ and E2E-BCQ), gvf-eval of its
checkpoint, and the Jackal-layout comparison with MPC and the kinematic controller."""

from __future__ import annotations

import json

from actors.collect import collect_worker
from actors.evaluation import offline_eval
from actors.evaluation.policies import checkpoint_policy
from common.cli import compose_run
from learner.offline_main import REPRESENTATION, train_offline

TINY_OFFLINE = [
    "scale.conv_channels=[4,8,8,8,8]",
    "scale.gvf_hidden=[32,32]",
    "scale.behaviour_hidden=[32,16]",
    "scale.batch_size=16",
    "agent.behaviour_warmup_updates=5",
    "agent.metrics_every=10",
    "learner.torch_threads=1",
]


def test_collect_train_offline_and_compare(tmp_path):
    data = tmp_path / "data"
    collect_worker(str(data), seed=0, worker=0, quota=300, cars=2, shard_size=100, env_kwargs={"track": "train"})
    common = [*TINY_OFFLINE, f"offline.dataset={data}", "offline.start=100"]
    gvf_cfg = compose_run([*common, "offline.method=gvf_bcq", "offline.gvf_updates=20", "offline.bcq_updates=20"])
    gvf_ckpt = train_offline(gvf_cfg, tmp_path / "gvf", show_progress=False)
    e2e_cfg = compose_run([*common, "offline.method=e2e_bcq", "offline.gvf_updates=5", "offline.bcq_updates=5"])
    e2e_ckpt = train_offline(e2e_cfg, tmp_path / "e2e", show_progress=False)

    assert (gvf_ckpt.parent / REPRESENTATION).exists()
    records = [json.loads(line) for line in (tmp_path / "gvf" / "offline_metrics.jsonl").read_text().splitlines()]
    assert [r["phase"] for r in records] == ["gvf", "gvf", "bcq", "bcq"]
    assert records[0]["train/rho_bar"] > 0 and "losses/td" in records[0] and "losses/loss_qvalue" in records[-1]
    assert records[-1]["update"] == 40  # BCQ's updates count on from Algorithm 2's
    for path, name, updates in ((gvf_ckpt, "GVF-BCQ", 40), (e2e_ckpt, "E2E-BCQ", 10)):
        _, meta = checkpoint_policy(path)  # what gvf-eval loads
        assert meta["agent"] == name and meta["updates"] == updates

    out = tmp_path / "compare"
    offline_eval.main(
        ["--policy", f"GVF-BCQ={gvf_ckpt}", "--policy", f"E2E-BCQ={e2e_ckpt}", "--out", str(out)]
        + [
            "--tracks",
            "dune",
        ]
    )
    drives = json.loads((out / "offline_eval.json").read_text())["drives"]
    assert len(drives) == 4 * 2 * 2 * 2  # methods x target speeds x markings x directions
    assert {d["method"] for d in drives} == {"GVF-BCQ", "E2E-BCQ", "MPC", "kinematic"}
    mpc = [d for d in drives if d["method"] == "MPC"]
    assert all(d["metrics"]["lap_completed"] == 1.0 for d in mpc)  # the baseline laps at both speeds
    text = (out / "offline_eval.md").read_text()
    assert "### dune" in text and "| E2E-BCQ | 0.4 m/s | damaged |" in text
    assert (out / "distributions.png").stat().st_size > 10_000
