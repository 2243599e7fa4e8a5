"""The evaluator role of a training run: every `eval.every_updates` learner updates it takes the
broadcast policy, drives the held-out roads without exploration noise, and logs the result
under eval/ in TensorBoard and as a line of eval.jsonl in the run folder (for learning curves).
It runs in its own process, so training never waits for it."""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path

from torch.utils.tensorboard import SummaryWriter

from actors.acting import Acting
from actors.evaluation.evaluate import evaluate, summary
from actors.evaluation.main import eval_env_kwargs
from actors.evaluation.policies import network_policy
from common import wire
from common.config.run import RunConfig
from common.keys import Keys
from common.transport import make_transport

log = logging.getLogger(__name__)


def run_evaluator(cfg: RunConfig, transport, run_dir: str | Path, stop: threading.Event) -> None:
    keys, every = Keys(cfg.run), cfg.eval.every_updates
    t = transport if transport is not None else make_transport(cfg.transport)
    acting = Acting(cfg.agent, cfg.scale, cfg.actor, 1, seed=0)
    rejects = wire.RejectCounter()
    writer = SummaryWriter(str(Path(run_dir) / "tb" / "eval"))
    due = every
    try:
        weights_in = t.subscribe(keys.weights, capacity=1, overflow="drop_old")
        while not stop.is_set():
            got = weights_in.get(timeout=0.5)
            msg = rejects.decode(got.payload, expect=wire.Weights, key=got.key) if got is not None else None
            if msg is None or msg.version < due:
                continue
            acting.load(msg)
            results = evaluate(network_policy(acting.policy, acting.lowdim), cfg.eval.split, tuple(cfg.eval.directions), **eval_env_kwargs(cfg))
            mean = summary(results)
            for key, value in mean.items():
                writer.add_scalar(f"eval/{key}", value, msg.version)
            writer.flush()
            with open(Path(run_dir) / "eval.jsonl", "a") as f:
                f.write(json.dumps({"updates": msg.version, "mean": mean, "drives": [{"track": r["track"], **r["metrics"]} for r in results]}) + "\n")
            log.info("eval at %d updates: laps %.0f%%, reward/s %.3f", msg.version, 100 * mean["lap_completed"], mean["reward_per_s"])
            due = (msg.version // every + 1) * every
    finally:
        writer.close()
        if transport is None:
            t.close()
