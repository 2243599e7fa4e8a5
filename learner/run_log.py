"""What the learner writes for people and the launcher: TensorBoard scalars (train/, losses/,
diag/, actors/, time/) and progress.json (replaced atomically: the launcher never reads half)."""

from __future__ import annotations

import json
import logging
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
# rho_bar below this: almost no stored action is one tau would take. In GVF-0.95 seed 0
# (docs/results.md) it fell from 2.2 to 1e-16 as steering went full-lock, and the GVFs stopped.
RHO_STARVED = 0.01

log = logging.getLogger(__name__)


class SupportWatch:
    """Says once, in the log, when the replay stops supporting tau (rho_bar < `floor`), and once
    when it does again (rho_bar >= 10 `floor`): the GVFs' loss is scaled by rho_bar, so while
    starved the predictions, and the policy's representation with them, barely move."""

    def __init__(self, floor: float = RHO_STARVED) -> None:
        self.floor = floor
        self.starved = False

    def check(self, rho_bar: float | None, updates: int) -> None:
        if rho_bar is None:
            return
        if not self.starved and rho_bar < self.floor:
            self.starved = True
            log.warning(
                "rho_bar %.2g < %g at update %d: the behaviour has left tau's support (it rarely takes an "
                "action near its last one), so the GVFs have all but stopped learning",
                rho_bar,
                self.floor,
                updates,
            )
        elif self.starved and rho_bar >= 10 * self.floor:
            self.starved = False
            log.info("rho_bar %.2g at update %d: tau is supported again, the GVFs learn", rho_bar, updates)


class RunLog:
    def __init__(self, run_dir: str | Path) -> None:
        self.run_dir = Path(run_dir)
        self.writer = SummaryWriter(str(self.run_dir / "tb"))
        self.support = SupportWatch()

    def write(self, progress: dict, metrics: dict, rates: dict) -> None:
        """One log point at `progress["updates"]`: the latest metrics, the rates and the counters."""
        step = progress["updates"]
        self.support.check(progress.get("rho_bar"), step)
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
