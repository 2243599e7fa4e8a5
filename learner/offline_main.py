"""`gvf-offline`: learn a driving policy from a gvf-collect dataset alone (learner.offline).

    gvf-offline offline.dataset=datasets/lanedrive offline.method=gvf_bcq    # GVF-BCQ
    gvf-offline offline.dataset=datasets/lanedrive offline.method=e2e_bcq    # E2E-BCQ
    gvf-eval checkpoint=outputs/.../checkpoints/offline                      # drive it

Writes under the run folder: offline_metrics.jsonl (losses, rho_bar, replay size per
`agent.metrics_every` updates), TensorBoard scalars, `offline.checkpoint_dir`/representation.pt
(GVF-BCQ's GVFs and g after Algorithm 2; a rerun with the same folder resumes from it) and
ckpt-<updates>.pt, the policy that gvf-eval reads.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path

import torch
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from torch.utils.tensorboard import SummaryWriter

from common import checkpoint
from common.config.agent import step_sizes
from common.config.run import RunConfig
from common.dataset import Dataset
from common.offline_policy import build_args, make_offline_policy
from learner.bcq import make_bcq
from learner.offline import BCQBatches, RepresentationTrainer, phi_table
from learner.service import resolve_device

log = logging.getLogger(__name__)
REPRESENTATION = "representation.pt"


class MetricsLog:
    """offline_metrics.jsonl and TensorBoard, one record per reported update."""

    def __init__(self, run_dir: Path):
        run_dir.mkdir(parents=True, exist_ok=True)
        self.file = open(run_dir / "offline_metrics.jsonl", "a")
        self.tb = SummaryWriter(str(run_dir / "tb"))

    def write(self, phase: str, update: int, metrics: dict[str, float]) -> None:
        self.file.write(json.dumps({"phase": phase, "update": update, **metrics}) + "\n")
        self.file.flush()
        for key, value in metrics.items():
            self.tb.add_scalar(f"{phase}/{key}", value, update)

    def close(self) -> None:
        self.file.close()
        self.tb.close()


def _bar(enabled: bool) -> Progress:
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    return Progress(*columns, disable=not enabled)


def learn_representation(run: RunConfig, dataset: Dataset, ckpt_dir: Path, metrics: MetricsLog, bar) -> dict:
    """Algorithm 2 for `offline.gvf_updates`, or the GVFs of an earlier run's representation.pt."""
    saved = ckpt_dir / REPRESENTATION
    if saved.exists():
        log.info("resuming from %s: Algorithm 2 is done", saved)
        return checkpoint.load(saved)
    o = run.offline
    trainer = RepresentationTrainer(
        run.agent,
        run.scale,
        dataset,
        updates=o.gvf_updates,
        loading=o.loading,
        replay=o.replay,
        start=o.start,
        load_fraction=o.load_fraction,
        seed=run.seed,
        device=resolve_device(run.learner.device),
    )
    task = bar.add_task("Algorithm 2 (GVFs, g)", total=o.gvf_updates)
    for i in range(o.gvf_updates):
        if out := trainer.step():
            metrics.write("gvf", i + 1, out)
        bar.update(task, completed=i + 1)
    nets = trainer.core.nets
    state = {"gvf": nets.gvf.state_dict(), "behaviour": nets.behaviour.state_dict(), "updates": o.gvf_updates}
    checkpoint.write(saved, state)
    return state


PAPER_REWARD = {"offset_weight": 1.0, "crash_penalty": 0.0}  # BCQ's reward is the dataset's, scaled


def unshaped(run: RunConfig, overrides: list[str]) -> RunConfig:
    """`run` with the scale's online reward shaping (`scale=small` sets a crash penalty) back at the
    paper's reward, which BCQ keeps; a value asked for in `overrides` stays, for train_offline to refuse."""
    asked = {o.split("=", 1)[0].lstrip("+~") for o in overrides}
    keep = {name: paper for name, paper in PAPER_REWARD.items() if f"scale.{name}" not in asked}
    return dataclasses.replace(run, scale=dataclasses.replace(run.scale, **keep))


def train_offline(run: RunConfig, out_dir: str | Path, show_progress: bool = True) -> Path:
    """Train `offline.method` from `offline.dataset`; returns the policy checkpoint's path."""
    o, agent, scale = run.offline, run.agent, run.scale
    out_dir = Path(out_dir)
    ckpt_dir = Path(o.checkpoint_dir) if Path(o.checkpoint_dir).is_absolute() else out_dir / o.checkpoint_dir
    for name, paper in PAPER_REWARD.items():
        if getattr(scale, name) != paper:
            raise ValueError(
                f"scale.{name}={getattr(scale, name)} is not applied offline (BCQ keeps the logged reward)"
            )
    dataset = Dataset.open(o.dataset)
    if agent.representation != "predictive" and o.method == "gvf_bcq":
        raise ValueError(f"offline.method=gvf_bcq needs a GVF agent (agent=gvf_ddpg), got {agent.name!r}")
    torch.set_num_threads(run.learner.torch_threads)
    torch.manual_seed(run.seed)
    metrics = MetricsLog(out_dir)
    device = resolve_device(run.learner.device)
    steps = step_sizes(agent, scale)
    bcq_args = {"discount": steps["discount"], "lr": o.lr}
    start = time.perf_counter()
    with _bar(show_progress) as bar:
        if o.method == "gvf_bcq":
            rep = learn_representation(run, dataset, ckpt_dir, metrics, bar)
            policy = make_offline_policy(o.method, agent, scale, build_args(o.method, agent, scale))
            policy.gvf.load_state_dict(rep["gvf"])
            policy.gvf.to(device).eval()
            table, mirrored = phi_table(policy.gvf, dataset, scale.reward_scale, mirrored=o.mirror > 0)
            batches = BCQBatches.table(table, scale.batch_size, run.seed, mirrored, o.mirror)
            bcq = make_bcq(policy.gvf.n_predictions + 3, **bcq_args)
            updates, offset = o.bcq_updates, o.gvf_updates
        else:
            batches = BCQBatches.images(dataset, scale.batch_size, scale.reward_scale, run.seed, o.mirror)
            bcq = make_bcq(0, image_channels=scale.conv_channels, **bcq_args)
            updates, offset = o.gvf_updates + o.bcq_updates, 0
        bcq.loss.to(device)
        task = bar.add_task(f"BCQ ({'phi' if o.method == 'gvf_bcq' else 'images'})", total=updates)
        for i in range(updates):
            out = bcq.update(batches.sample().to(device))
            if (i + 1) % agent.metrics_every == 0:
                metrics.write("bcq", offset + i + 1, {f"losses/{k}": float(v) for k, v in out.items()})
            bar.update(task, completed=i + 1)
    metrics.close()
    policy = make_offline_policy(o.method, agent, scale, build_args(o.method, agent, scale))
    if o.method == "gvf_bcq":
        policy.gvf.load_state_dict(rep["gvf"])
    policy.bcq.load_state_dict(bcq.loss.policy().state_dict())
    state = checkpoint.policy_entries(policy.state_dict(), agent, scale, offset + updates)
    state["offline"] = {"method": o.method, "build": build_args(o.method, agent, scale)}
    state["offline_seconds"] = round(time.perf_counter() - start, 1)
    return checkpoint.save(ckpt_dir, offset + updates, state)


def task(cfg) -> None:
    from hydra.core.hydra_config import HydraConfig

    from common.config.run import to_objects

    run, _, _ = to_objects(cfg)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    run = unshaped(run, list(HydraConfig.get().overrides.task))
    path = train_offline(run, out_dir, show_progress=run.progress)
    print(f"policy: {path}\nevaluate it: gvf-eval checkpoint={path}")


def main() -> None:
    from common.cli import hydra_entry

    hydra_entry(task)()


if __name__ == "__main__":
    main()
