"""`gvf-eval`: evaluate a checkpoint (`checkpoint=PATH`) or the kinematic controller
(`policy=kinematic`) on the held-out roads and write eval.json, eval.md and figures; with
`eval.runs=DIR`, also learning curves from the eval.jsonl files of the runs under DIR.
`env=torcs` drives the TORCS test roads (after `make torcs`), each once, its own way."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from actors.envs.simulators import is_torcs, vehicle
from actors.evaluation.evaluate import evaluate
from actors.evaluation.policies import checkpoint_policy, kinematic_policy
from actors.evaluation.report import learning_curves, write_report
from common.config.env import DamageConfig
from common.config.run import RunConfig

log = logging.getLogger(__name__)
DEFAULT_DAMAGE = DamageConfig(gap_fraction=0.3, fade_fraction=0.3, distractors_per_100m=2.0)


def eval_env_kwargs(cfg: RunConfig) -> dict:
    env = dataclasses.asdict(cfg.env)
    for key in ("track", "direction", "random_start", "lighting"):  # env.id stays: it names the simulator
        env.pop(key)
    if cfg.eval.damaged and not any(dataclasses.asdict(cfg.env.damage).values()):
        env["damage"] = dataclasses.asdict(DEFAULT_DAMAGE)
    return env


def run_eval(cfg: RunConfig, out_dir: str | Path) -> list[Path]:
    if cfg.policy == "kinematic":
        policy, title = kinematic_policy(vehicle(cfg.env)), "kinematic controller"
    elif cfg.policy == "checkpoint":
        if not cfg.checkpoint:
            raise ValueError("gvf-eval needs checkpoint=PATH (a ckpt-*.pt file or a run folder), or policy=kinematic")
        policy, meta = checkpoint_policy(cfg.checkpoint)
        title = f"{meta['agent']} after {meta['updates']} updates"
    else:
        raise ValueError(f"policy must be 'checkpoint' or 'kinematic', got {cfg.policy!r}")
    if cfg.eval.video and is_torcs(cfg.env):  # refused before any drive, not after
        raise ValueError("eval.video draws LaneDrive's top-down view: not available with env.id=TorcsDrive-v0")
    results = evaluate(policy, cfg.eval.split, tuple(cfg.eval.directions), **eval_env_kwargs(cfg))
    title += " (damaged markings)" if cfg.eval.damaged else ""
    files = write_report(results, out_dir, title)
    if cfg.eval.video:
        from actors.evaluation.video import record_lap, write_video

        frames, _ = record_lap(
            policy, results[0]["track"].removesuffix("-r"), results[0]["direction"], **eval_env_kwargs(cfg)
        )
        files.append(write_video(frames, Path(out_dir) / "lap.gif"))
    if cfg.eval.runs:
        runs = sorted({p.parent for p in Path(cfg.eval.runs).glob("**/eval.jsonl")})
        curve = learning_curves(runs, Path(out_dir) / "learning_curves.png")
        files += [curve] if curve else []
    return files


def task(cfg) -> None:
    from hydra.core.hydra_config import HydraConfig

    from common.config.run import to_objects

    run, _, _ = to_objects(cfg)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    out = run.eval.out_dir or HydraConfig.get().runtime.output_dir
    for f in run_eval(run, out):
        print(f)
    print((Path(out) / "eval.md").read_text())


def main() -> None:
    from common.cli import hydra_entry

    hydra_entry(task)()
