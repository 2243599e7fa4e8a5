"""What the learner writes for people and the launcher: TensorBoard scalars (train/, losses/,
diag/, actors/, time/) and progress.json (replaced atomically: the launcher never reads half)."""

from __future__ import annotations

import json
import os
from pathlib import Path

from torch.utils.tensorboard import SummaryWriter

ACTOR_SCALARS = (
    "alive",
    "episodes",
    "lost_chunks",
    "rejected",
    "inbox_dropped",
    "inbox_waited",
    "flow_paused",
    "return_mean",
    "policy_lag",
    "rho_lag",
)


class RunLog:
    def __init__(self, run_dir: str | Path) -> None:
        self.run_dir = Path(run_dir)
        self.writer = SummaryWriter(str(self.run_dir / "tb"))

    def write(self, progress: dict, metrics: dict, rates: dict) -> None:
        """One log point at `progress["updates"]`: the latest metrics, the rates and the counters."""
        step = progress["updates"]
        w = self.writer
        for key, value in metrics.items():
            w.add_scalar(key, value, step)
        w.add_scalar("train/updates_per_s", rates["updates_per_s"], step)
        w.add_scalar("train/inserts_per_s", rates["env_steps_per_s"], step)
        w.add_scalar("train/replay_size", progress["replay"], step)
        values = {**progress, "alive": progress["actors_alive"]}
        for key in ACTOR_SCALARS:
            if values.get(key) is not None:
                w.add_scalar(f"actors/{key}", float(values[key]), step)
        w.add_scalar("time/ingest_fraction", rates["ingest_fraction"], step)
        w.add_scalar("time/train_fraction", rates["train_fraction"], step)
        tmp = self.run_dir / ".progress.json.tmp"
        tmp.write_text(
            json.dumps(
                {**progress, "updates_per_s": rates["updates_per_s"], "env_steps_per_s": rates["env_steps_per_s"]}
            )
        )
        os.replace(tmp, self.run_dir / "progress.json")

    def close(self) -> None:
        self.writer.close()
