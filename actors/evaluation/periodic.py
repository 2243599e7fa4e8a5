"""The evaluator role of a training run: every `eval.every_updates` learner updates it takes the
broadcast policy, drives the held-out roads without exploration noise, and logs the result
under eval/ in TensorBoard and as a line of eval.jsonl in the run folder (for learning curves).
It runs in its own process, so training never waits for it. Each evaluation also drives the
validation roads (`eval.validation_tracks`: procedural roads, neither train nor test; on TORCS,
roads.json's validation roads, train roads held out of sampling), and the policy of the best
validation so far (`common.selection`: most laps, then least near-out-of-lane, then least mean
abs(alpha), then reward per second) is kept as checkpoints/best-policy.pt, which gvf-eval and the
comparison load like a learner checkpoint. Choosing on the test roads themselves would make any
number reported from that policy optimistic."""

from __future__ import annotations

import json
import logging
import threading
import time
from pathlib import Path

import torch
from torch.utils.tensorboard import SummaryWriter

from actors.acting import Acting
from actors.envs.simulators import is_torcs
from actors.envs.tracks import track_names
from actors.evaluation.evaluate import evaluate, summary
from actors.evaluation.main import eval_env_kwargs
from actors.evaluation.policies import network_policy
from actors.weights_client import WeightsClient
from common import checkpoint, wire
from common.config.run import RunConfig
from common.keys import Keys
from common.selection import BEST, better

log = logging.getLogger(__name__)


def validation_tracks(names: list[str]) -> list[str]:
    """The validation roads, refused (naming the field) if empty or holding a train or test road."""
    library = set(track_names("all"))
    bad = [n for n in names if n.removesuffix("-r") in library]
    if bad or not names:
        raise ValueError(
            f"eval.validation_tracks must be roads neither train nor test (procedural:SEED), got {list(names)}"
        )
    return list(names)


def validation_roads(cfg: RunConfig) -> list[str]:
    """The roads the best policy is chosen on: `eval.validation_tracks` on LaneDrive, roads.json's
    validation roads on TORCS (which has no procedural roads; actors never sample those)."""
    if is_torcs(cfg.env):
        from actors.envs.torcs.roads import road_names

        return road_names("validation")
    return validation_tracks(cfg.eval.validation_tracks)


def validate(policy, cfg: RunConfig) -> dict:
    """Mean metrics of `policy` on the validation roads: what selects the best policy."""
    return summary(
        evaluate(policy, directions=tuple(cfg.eval.directions), tracks=validation_roads(cfg), **eval_env_kwargs(cfg))
    )


def save_best(path: Path, acting: Acting, cfg: RunConfig, updates: int, validation: dict, test: dict) -> None:
    """The evaluated policy in the layout of common.checkpoint, atomically."""
    state = checkpoint.policy_entries(acting.policy.state_dict(), cfg.agent, cfg.scale, updates)
    checkpoint.write(path, {**state, "validation": validation, "eval": test})


def drive_online(acting: Acting, cfg: RunConfig) -> dict | None:
    """The online policy's mean metrics on the evaluated roads, where the evaluator keeps it
    (`eval.online_too`) and the weights carried an average; else None."""
    if acting.online is None or not acting.has_average:
        return None
    return summary(drive_evaluated_roads(network_policy(acting.online, acting.lowdim), cfg))


def drive_evaluated_roads(policy, cfg: RunConfig) -> list[dict]:
    """The evaluated roads (`eval.split`, `eval.directions`) driven once by `policy`."""
    return evaluate(policy, cfg.eval.split, tuple(cfg.eval.directions), **eval_env_kwargs(cfg))


def evaluator_role(ctx) -> None:
    """The evaluator role (`common.roles`)."""
    run_evaluator(ctx.cfg, ctx.transport, ctx.run_dir, ctx.stop)


def run_evaluator(cfg: RunConfig, t, run_dir: str | Path, stop: threading.Event) -> None:
    keys, every = Keys(cfg.run), cfg.eval.every_updates
    # torch's default (a thread per core) fights the simulators for the cores: one TORCS evaluation of
    # 54 steps took 20 s with 2 threads, 2.9 s with 1, on the 2 loaded cores here
    torch.set_num_threads(cfg.actor.torch_threads)
    acting = Acting(cfg.agent, cfg.scale, cfg.actor, 1, seed=0, deployed=True, keep_online=cfg.eval.online_too)
    rejects = wire.RejectCounter()
    writer = SummaryWriter(str(Path(run_dir) / "tb" / "eval"))
    due = every
    best_path = Path(run_dir) / "checkpoints" / BEST
    validation_roads(cfg)  # a bad list is refused before any drive
    best = (
        checkpoint.load(best_path).get("validation") if best_path.exists() else None
    )  # a restarted evaluator keeps the bar
    try:
        weights = WeightsClient(t, keys, "evaluator", acting, rejects, fetch=False)
        while not stop.is_set():
            weights.poll(timeout=0.5)
            if acting.version < due:
                continue
            version = acting.version  # the policy evaluated now (newer broadcasts wait in the inbox)
            policy = network_policy(acting.policy, acting.lowdim)
            results = drive_evaluated_roads(policy, cfg)
            mean, val = summary(results), validate(policy, cfg)
            online = drive_online(acting, cfg)
            for key, value in mean.items():
                writer.add_scalar(f"eval/{key}", value, version)
            for key, value in (online or {}).items():
                writer.add_scalar(f"eval/online_{key}", value, version)
            for key in ("lap_completed", "reward_per_s"):
                writer.add_scalar(f"eval/validation_{key}", val[key], version)
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
                        {
                            "updates": version,
                            "time": time.time(),
                            "mean": mean,
                            "validation": val,
                            "drives": drives,
                            **({"online": online} if online is not None else {}),
                        }
                    )
                    + "\n"
                )
            log.info(
                "eval at %d updates: laps %.0f%% (validation %.0f%%), reward/s %.3f",
                version,
                100 * mean["lap_completed"],
                100 * val["lap_completed"],
                mean["reward_per_s"],
            )
            if better(val, best):
                save_best(best_path, acting, cfg, version, val, mean)
                best = val
            due = (version // every + 1) * every
    finally:
        writer.close()
