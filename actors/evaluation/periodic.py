"""The evaluator role of a training run: every `eval.every_updates` learner updates it takes the
broadcast policy, drives the held-out roads without exploration noise, and logs the result
under eval/ in TensorBoard and as a line of eval.jsonl in the run folder (for learning curves).
It runs in its own process, so training never waits for it. Each evaluation also drives the
validation roads (`eval.validation_tracks`: procedural roads, neither train nor test), and the
policy of the best validation so far (most laps, then reward per second) is kept as
checkpoints/best-policy.pt, which gvf-eval and the comparison load like a learner checkpoint.
Choosing on the test roads themselves would make any number reported from that policy optimistic."""

from __future__ import annotations

import json
import logging
import threading
import time
from pathlib import Path

from torch.utils.tensorboard import SummaryWriter

from actors.acting import Acting
from actors.envs.tracks import track_names
from actors.evaluation.evaluate import evaluate, summary
from actors.evaluation.main import eval_env_kwargs
from actors.evaluation.policies import network_policy
from common import checkpoint, wire
from common.config.run import RunConfig
from common.keys import Keys

log = logging.getLogger(__name__)
BEST = checkpoint.BEST


def better(mean: dict, best: dict | None) -> bool:
    """More laps completed, or as many at a higher reward per second."""
    return best is None or (mean["lap_completed"], mean["reward_per_s"]) > (best["lap_completed"], best["reward_per_s"])


def validation_tracks(names: list[str]) -> list[str]:
    """The validation roads, refused (naming the field) if empty or holding a train or test road."""
    library = set(track_names("all"))
    bad = [n for n in names if n.removesuffix("-r") in library]
    if bad or not names:
        raise ValueError(
            f"eval.validation_tracks must be roads neither train nor test (procedural:SEED), got {list(names)}"
        )
    return list(names)


def validate(policy, cfg: RunConfig) -> dict:
    """Mean metrics of `policy` on the validation roads: what selects the best policy."""
    return summary(
        evaluate(
            policy,
            directions=tuple(cfg.eval.directions),
            tracks=validation_tracks(cfg.eval.validation_tracks),
            **eval_env_kwargs(cfg),
        )
    )


def save_best(path: Path, acting: Acting, cfg: RunConfig, updates: int, validation: dict, test: dict) -> None:
    """The evaluated policy in the layout of common.checkpoint, atomically."""
    state = checkpoint.policy_entries(acting.policy.state_dict(), cfg.agent, cfg.scale, updates)
    checkpoint.write(path, {**state, "validation": validation, "eval": test})


def evaluator_role(ctx) -> None:
    """The evaluator role (`common.roles`)."""
    run_evaluator(ctx.cfg, ctx.transport, ctx.run_dir, ctx.stop)


def run_evaluator(cfg: RunConfig, t, run_dir: str | Path, stop: threading.Event) -> None:
    keys, every = Keys(cfg.run), cfg.eval.every_updates
    acting = Acting(cfg.agent, cfg.scale, cfg.actor, 1, seed=0)
    rejects = wire.RejectCounter()
    writer = SummaryWriter(str(Path(run_dir) / "tb" / "eval"))
    due = every
    best_path = Path(run_dir) / "checkpoints" / BEST
    validation_tracks(cfg.eval.validation_tracks)  # a bad list is refused before any drive
    best = (
        checkpoint.load(best_path).get("validation") if best_path.exists() else None
    )  # a restarted evaluator keeps the bar
    try:
        weights_in = t.subscribe(keys.subscribe("weights", "evaluator"), capacity=1, overflow="drop_old")
        while not stop.is_set():
            got = weights_in.get(timeout=0.5)
            msg = rejects.decode(got.payload, expect=wire.Weights, key=got.key) if got is not None else None
            if msg is None or msg.version < due:
                continue
            if not acting.adopt(msg, rejects, got.key):
                continue  # counted: a set that does not fit this policy is never driven
            policy = network_policy(acting.policy, acting.lowdim)
            results = evaluate(policy, cfg.eval.split, tuple(cfg.eval.directions), **eval_env_kwargs(cfg))
            mean, val = summary(results), validate(policy, cfg)
            for key, value in mean.items():
                writer.add_scalar(f"eval/{key}", value, msg.version)
            for key in ("lap_completed", "reward_per_s"):
                writer.add_scalar(f"eval/validation_{key}", val[key], msg.version)
            writer.flush()
            drives = [
                {
                    "track": r["track"],
                    **r["metrics"],
                    "end_progress": float(r["trace"]["progress"][-1]) if len(r["trace"]["progress"]) else 0.0,
                }
                for r in results
            ]
            with open(Path(run_dir) / "eval.jsonl", "a") as f:
                f.write(
                    json.dumps(
                        {"updates": msg.version, "time": time.time(), "mean": mean, "validation": val, "drives": drives}
                    )
                    + "\n"
                )
            log.info(
                "eval at %d updates: laps %.0f%% (validation %.0f%%), reward/s %.3f",
                msg.version,
                100 * mean["lap_completed"],
                100 * val["lap_completed"],
                mean["reward_per_s"],
            )
            if better(val, best):
                save_best(best_path, acting, cfg, msg.version, val, mean)
                best = val
            due = (msg.version // every + 1) * every
    finally:
        writer.close()
