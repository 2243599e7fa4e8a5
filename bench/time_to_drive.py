"""Time to drive: wall-clock minutes until GVF-DDPG (small CPU config, 2 actors) completes a full
lap of every held-out road, judged by the periodic noise-free evaluation of a real `gvf-train` run.

Usage: python bench/time_to_drive.py [--budget-min 30] [--eval-every 500] [-- extra Hydra overrides]
Stops at the first evaluation where every test lap (both directions) is completed, or at the
budget (with --until-budget, always at the budget: does the policy keep lapping?). Then the
run's last checkpoint and its validation-selected best policy are driven on the test roads.
The last line printed is one JSON object; its `evaluations` list every evaluation as [minute
it was seen, learner updates, test laps, validation laps]. With --out FILE the JSON is also
written there, and a FILE that exists already is printed instead of run again (resumable).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent


def read_lines(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def read_progress(run_dir: Path) -> dict:
    """The run's progress.json (rewritten every few seconds by gvf-train), or {} before the first."""
    try:
        return json.loads((run_dir / "progress.json").read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}


def drive_test_roads(path: Path) -> dict | None:
    """Test laps, near-out-of-lane and mean |alpha| of the policy in a checkpoint file or folder."""
    from actors.evaluation.evaluate import evaluate, summary
    from actors.evaluation.policies import checkpoint_policy

    try:
        policy, meta = checkpoint_policy(path)
    except (FileNotFoundError, ValueError):
        return None
    results = evaluate(policy)
    mean = summary(results)
    return {
        "updates": meta["updates"],
        "laps": int(sum(r["metrics"]["lap_completed"] for r in results)),
        "near_out_of_lane": mean["near_out_of_lane"],
        "offcenteredness": mean["offcenteredness"],
        "average_speed": mean["average_speed"],
        "failed": sorted(r["track"] for r in results if not r["metrics"]["lap_completed"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--budget-min", type=float, default=30.0, help="give up after this many minutes")
    parser.add_argument("--eval-every", type=int, default=500, help="learner updates between evaluations")
    parser.add_argument("--run-dir", default=None, help="keep the run here (default: a temporary folder)")
    parser.add_argument(
        "--until-budget",
        action="store_true",
        help="go on after the first evaluation with every lap, to see if it holds",
    )
    parser.add_argument("--out", type=Path, default=None, help="also write the JSON here; skip the run if it exists")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for gvf-train")
    args = parser.parse_args()
    if args.out is not None and args.out.exists():
        print(args.out.read_text().strip())
        return
    run_dir = Path(args.run_dir or tempfile.mkdtemp(prefix="time_to_drive_"))
    run_dir.mkdir(parents=True, exist_ok=True)
    cmd = [
        str(BIN / "gvf-train"),
        "agent=gvf_ddpg",
        "actors.count=2",
        "progress=false",
        "run=time_to_drive",
        f"eval.every_updates={args.eval_every}",
        f"hydra.run.dir={run_dir}",
        *args.overrides,
    ]
    start = time.monotonic()
    proc = subprocess.Popen(
        cmd,
        stdout=open(run_dir / "train.out", "wb"),
        stderr=subprocess.STDOUT,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    best, done_min, steps_at_done, first_all = None, None, None, None
    seen: dict[int, list] = {}  # updates -> [minute first seen, updates, test laps of 12, validation laps of 12]
    try:
        while time.monotonic() - start < args.budget_min * 60 and proc.poll() is None:
            time.sleep(5)
            minute = round((time.monotonic() - start) / 60, 2)
            for e in read_lines(run_dir / "eval.jsonl"):
                if e["updates"] in seen:
                    continue
                laps = round(e["mean"]["lap_completed"] * len(e["drives"]))
                val = e.get("validation", {}).get("lap_completed")
                seen[e["updates"]] = [
                    minute,
                    e["updates"],
                    laps,
                    None if val is None else round(val * len(e["drives"])),
                ]
                if best is None or e["mean"]["lap_completed"] > best["mean"]["lap_completed"]:
                    best = e
                print(
                    f"{minute:5.1f} min  {e['updates']} updates  laps {laps}/{len(e['drives'])}  reward/s {e['mean']['reward_per_s']:.2f}",
                    flush=True,
                )
                if e["mean"]["lap_completed"] >= 1.0 and done_min is None:
                    done_min, steps_at_done, first_all = minute, read_progress(run_dir).get("inserted"), e
            if done_min is not None and not args.until_budget:
                break
    finally:
        elapsed = (time.monotonic() - start) / 60
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
    progress = read_progress(run_dir)
    evaluations = sorted(seen.values(), key=lambda x: x[1])
    after = [laps for _, updates, laps, _ in evaluations if first_all is not None and updates > first_all["updates"]]
    n_laps = len(first_all["drives"]) if first_all else 12
    last, selected = (
        drive_test_roads(run_dir / "checkpoints"),
        drive_test_roads(run_dir / "checkpoints" / "best-policy.pt"),
    )
    result = {
        "minutes_to_all_test_laps": done_min,
        "env_steps": steps_at_done if done_min is not None else progress.get("inserted"),  # at the laps, else in all
        "env_steps_run": progress.get("inserted"),
        "updates": progress.get("updates"),
        "budget_min": args.budget_min,
        "minutes_run": round(elapsed, 2),
        "reached": done_min is not None,
        "evaluations_with_all_laps": sum(laps == len(best["drives"]) for _, _, laps, _ in seen.values()) if best else 0,
        "evaluations_after_first_all_laps": len(after),
        "fraction_after_with_11_laps": (sum(laps >= n_laps - 1 for laps in after) / len(after)) if after else None,
        "first_all_laps_near_out_of_lane": first_all["mean"]["near_out_of_lane"] if first_all else None,
        "first_all_laps_offcenteredness": first_all["mean"]["offcenteredness"] if first_all else None,
        "last_checkpoint": last,
        "validation_selected": selected,
        "best_lap_fraction": best["mean"]["lap_completed"] if best else 0.0,
        "best_at_updates": best["updates"] if best else None,
        "env_steps_per_s": progress.get("env_steps_per_s"),
        "updates_per_s": progress.get("updates_per_s"),
        "run_dir": str(run_dir),
        "overrides": args.overrides,
        "evaluations": evaluations,  # [minute, updates, test laps, validation laps]
    }
    line = json.dumps(result)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(line + "\n")
    print(line)


if __name__ == "__main__":
    main()
