"""The paper's comparison as resumable jobs, one `gvf-train` run per (agent variant, seed), each
leaving a small JSON summary (committed under docs/results/runs/) from which `compare` builds
every table and figure; checkpoints stay in the scratch folder and are never committed.

    python -m actors.evaluation.study --variants gvf_ddpg ddpg_image --seeds 0 1 2 3 4 --minutes 15
    python -m actors.evaluation.compare docs/results/runs
    python -m actors.evaluation.study --variants gvf_ddpg --seeds 1 --out docs/results/levers/x -- scale.crash_penalty=150

Hydra overrides for every run go last, after `--` (otherwise `--seeds` reads them as seeds).

A job whose summary exists is skipped, so an interrupted study continues where it stopped (a
summary records the scale it trained at, and a job at another one under the same --out is refused; the
interrupted job starts again; its partial folder is moved aside as `<job>.interrupted-<time>`; a
run that ends short of its update budget, or without one of its minutes, writes no summary). A
summary holds the run's periodic evaluations (minute, updates, test and validation metrics,
per road: lap, episode length, where the drive ended) and the final policies (the last
checkpoint and the validation-selected best-policy.pt, with the ranking that selected it) driven on
the test roads, clean and with damaged markings, with each clean drive's lane centeredness along
the lap (downsampled), and the learner's diagnostics binned every 500 updates (`learner_curves`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from actors.evaluation.evaluate import evaluate, summary
from actors.evaluation.learner_curves import learner_curves
from actors.evaluation.main import DEFAULT_DAMAGE
from actors.evaluation.periodic import BEST
from actors.evaluation.policies import checkpoint_policy
from common.selection import RANKING

BIN = Path(sys.executable).parent
VARIANTS = ("gvf_ddpg", "gvf_ddpg_g0", "gvf_ddpg_g095", "ddpg_image", "ddpg_lowdim")
TRACE_POINTS = 200  # lane centeredness along a lap, downsampled: the summary stays small
DRIVE_KEYS = ("lap_completed", "episode_length")  # per road at each evaluation; the means carry the rest


def rounded(value, digits: int = 4):
    """Floats to `digits` decimals, recursively: a summary stays ~100 KB, and nothing read from it needs more."""
    if isinstance(value, float):
        return round(value, digits)
    if isinstance(value, dict):
        return {k: rounded(v, digits) for k, v in value.items()}
    if isinstance(value, list):
        return [rounded(v, digits) for v in value]
    return value


def summary_path(out: Path, variant: str, seed: int) -> Path:
    return out / variant / f"seed{seed}.json"


def recipe(variant: str, overrides: list[str]) -> str:
    """The scale a job trains at, composed as gvf-train will (a bad override is refused before the run):
    a resumed study refuses to put summaries of two recipes under one --out."""
    from common.cli import compose_run

    return compose_run([f"agent={variant}", *(o for o in overrides if not o.startswith("hydra."))]).scale.name


def _trace(result: dict) -> dict:
    progress, alpha = result["trace"]["progress"], result["trace"]["alpha"]
    keep = np.unique(np.linspace(0, len(alpha) - 1, min(TRACE_POINTS, len(alpha))).astype(int))
    return {"progress": np.round(progress[keep], 4).tolist(), "alpha": np.round(alpha[keep], 4).tolist()}


def final_drives(path: Path, traces: bool = True) -> dict | None:
    """The policy of a checkpoint on the test roads, clean (with traces) and with damaged markings."""
    try:
        policy, meta = checkpoint_policy(path)
    except (FileNotFoundError, ValueError):
        return None
    out: dict = {"updates": meta["updates"]}
    for condition, env in (("clean", {}), ("damaged", {"damage": dataclasses.asdict(DEFAULT_DAMAGE)})):
        results = evaluate(policy, **env)
        out[condition] = {"mean": summary(results), "drives": [{"track": r["track"], **r["metrics"]} for r in results]}
        if condition == "clean" and traces:
            out[condition]["traces"] = {r["track"]: _trace(r) for r in results}
    return out


def read_progress(run_dir: Path) -> dict:
    """The learner's progress.json at the end of a run ({} if it wrote none)."""
    path = run_dir / "progress.json"
    return json.loads(path.read_text()) if path.exists() else {}


def summarize(run_dir: Path, start: float, job: dict) -> dict:
    """The small record of one finished run (module docstring)."""
    evaluations = []
    eval_file = run_dir / "eval.jsonl"
    for line in eval_file.read_text().splitlines() if eval_file.exists() else []:
        e = json.loads(line)
        evaluations.append(
            {
                "updates": e["updates"],
                "minute": round((e["time"] - start) / 60, 2) if "time" in e else None,
                "mean": e["mean"],
                "validation": e.get("validation"),
                **({"online": e["online"]} if "online" in e else {}),
                "drives": [
                    {"track": d["track"], **{k: d[k] for k in (*DRIVE_KEYS, "end_progress") if k in d}}
                    for d in e["drives"]
                ],
            }
        )
    progress = read_progress(run_dir)
    return {
        **job,
        "progress": progress,
        "evaluations": evaluations,
        "last": final_drives(run_dir / "checkpoints"),
        "selected": final_drives(run_dir / "checkpoints" / BEST, traces=False),
        "selected_by": RANKING,
        "learner": learner_curves(run_dir / "tb"),
    }


def write_summary(record: dict, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(rounded(record)))
    tmp.replace(path)  # a half-written summary would be skipped as done
    return path


def adopt(
    run_dir: Path, variant: str, seed: int, minutes: float, eval_every: int, out: Path, overrides: list[str]
) -> Path:
    """The summary of a finished run made outside the study (e.g. by bench/time_to_drive.py with the
    same settings); its start is when Hydra wrote the run's config."""
    start = (run_dir / ".hydra" / "config.yaml").stat().st_mtime
    job = {"variant": variant, "seed": seed, "minutes": minutes, "eval_every": eval_every, "overrides": overrides}
    return write_summary(
        summarize(run_dir, start, {**job, "adopted_from": str(run_dir)}), summary_path(out, variant, seed)
    )


def run_job(
    variant: str,
    seed: int,
    minutes: float,
    eval_every: int,
    out: Path,
    work: Path,
    overrides: list[str],
    updates: int = 0,
) -> Path:
    """One training run and its summary; skipped if the summary exists. `updates` > 0 ends the run
    at that many learner updates (`minutes` is then only a cap)."""
    scale, path = recipe(variant, overrides), summary_path(out, variant, seed)
    if path.exists():
        done = json.loads(path.read_text()).get("scale")  # None: summaries written before it was recorded
        if done not in (None, scale):
            raise RuntimeError(f"{path} trained at scale {done}, this job at {scale}: give the study another --out")
        print(f"skip {variant} seed {seed}: {path} exists", flush=True)
        return path
    run_dir = work / f"{variant}-seed{seed}"
    if run_dir.exists() and any(run_dir.iterdir()):
        # an interrupted attempt: its eval.jsonl (appended to) and checkpoints would leak into this summary
        aside = run_dir.with_name(f"{run_dir.name}.interrupted-{time.strftime('%Y%m%dT%H%M%S')}")
        run_dir.rename(aside)
        print(f"an interrupted attempt of {variant} seed {seed} moved to {aside}", flush=True)
    run_dir.mkdir(parents=True, exist_ok=True)
    cmd = [
        str(BIN / "gvf-train"),
        f"agent={variant}",  # at the root config's scale unless an override after `--` names another
        "actors.count=2",
        "progress=false",
        f"run=study-{variant}-{seed}",
        f"seed={seed}",
        f"max_seconds={minutes * 60:.0f}",
        f"eval.every_updates={eval_every}",
        f"hydra.run.dir={run_dir}",
        *([f"learner.max_updates={updates}"] if updates > 0 else []),
        *overrides,
    ]
    print(f"run {variant} seed {seed} for {minutes} min in {run_dir}", flush=True)
    start = time.time()
    with open(run_dir / "train.out", "wb") as log:
        subprocess.run(
            cmd,
            stdout=log,
            stderr=subprocess.STDOUT,
            timeout=minutes * 60 + 600,
            env={**os.environ, "OMP_NUM_THREADS": "1"},
            check=True,
        )
    elapsed = time.time() - start
    done = read_progress(run_dir).get("updates", 0)
    if (updates > 0 and done < updates) or (updates <= 0 and elapsed < 0.95 * minutes * 60):
        # a run stopped from outside (SIGTERM ends gvf-train cleanly, rc 0) must not be skipped as finished
        raise RuntimeError(
            f"{variant} seed {seed} stopped early: {done} updates in {elapsed / 60:.1f} min (budget: "
            f"{updates or 'none'} updates, {minutes} min); no summary written, a rerun starts it again"
        )
    job = {
        "variant": variant,
        "seed": seed,
        "scale": scale,
        "minutes": minutes,
        "updates_budget": updates,
        "eval_every": eval_every,
        "overrides": overrides,
        "wall_minutes": round(elapsed / 60, 2),
    }
    return write_summary(summarize(run_dir, start, job), path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--minutes", type=float, default=15.0, help="wall-clock budget of each run")
    parser.add_argument(
        "--updates",
        type=int,
        default=0,
        help="end each run at this many learner updates, --minutes then only a cap: the machine's speed "
        "changes the wall time, not the training (a wall-clock budget gives a slower machine fewer updates)",
    )
    parser.add_argument("--eval-every", type=int, default=500, help="learner updates between evaluations")
    parser.add_argument("--out", type=Path, default=Path("docs/results/runs"), help="where summaries go (commit these)")
    parser.add_argument("--work", type=Path, default=Path("runs/study"), help="scratch: run folders, checkpoints")
    parser.add_argument("--adopt", type=Path, default=None, help="summarize this finished run (one variant and seed)")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for every run, after `--`")
    args = parser.parse_args()
    if args.adopt is not None:
        if len(args.variants) != 1 or len(args.seeds) != 1:
            parser.error("--adopt summarizes one run: give one --variants and one --seeds")
        (variant,), (seed,) = args.variants, args.seeds
        print(adopt(args.adopt, variant, seed, args.minutes, args.eval_every, args.out, args.overrides))
        return
    for seed in args.seeds:  # seed-major: a partial study has every variant at its first seeds
        for variant in args.variants:
            print(
                run_job(
                    variant, seed, args.minutes, args.eval_every, args.out, args.work, args.overrides, args.updates
                ),
                flush=True,
            )


if __name__ == "__main__":
    main()
