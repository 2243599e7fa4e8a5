"""One comparison table and figure set from a reproduction multirun (`gvf-train -m +experiment=reproduce`):
every run's final checkpoint (or, with --best, the policy of its best periodic evaluation)
evaluated on the held-out roads, clean and with damaged lane
markings, mean and std over seeds per agent variant, with the kinematic controller as
reference, and learning curves per variant.

    python -m actors.evaluation.compare MULTIRUN_DIR [--out docs/results] [--best]
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import defaultdict
from pathlib import Path

import numpy as np
import yaml

from actors.evaluation.evaluate import evaluate, summary
from actors.evaluation.main import DEFAULT_DAMAGE
from actors.evaluation.periodic import BEST
from actors.evaluation.policies import checkpoint_policy, kinematic_policy
from actors.evaluation.report import COLUMNS, learning_curves


def job_agent(job: Path) -> str:
    overrides = yaml.safe_load((job / ".hydra" / "overrides.yaml").read_text())
    return next((o.split("=", 1)[1] for o in overrides if o.startswith("agent=")), "gvf_ddpg")


CONDITIONS = {"test roads": {}, "test roads, damaged lane markings": {"damage": dataclasses.asdict(DEFAULT_DAMAGE)}}


def table(per_agent: dict[str, list[dict]], reference: dict) -> list[str]:
    """Markdown rows: mean ± std over the runs of each agent, then the reference controller."""
    head = "| method | runs | " + " | ".join(f"{h} {a}" for _, h, a in COLUMNS) + " |"
    lines = [head, "|" + " --- |" * (len(COLUMNS) + 2)]
    for agent, runs in sorted(per_agent.items()):
        cells = [f"{np.mean([r[k] for r in runs]):.3f} ± {np.std([r[k] for r in runs]):.3f}" for k, _, _ in COLUMNS]
        lines.append(f"| {agent} | {len(runs)} | " + " | ".join(cells) + " |")
    lines.append("| kinematic controller | - | " + " | ".join(f"{reference[k]:.3f}" for k, _, _ in COLUMNS) + " |")
    return lines


def compare(multirun: Path, out: Path, best: bool = False) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, dict[str, list[dict]]] = {c: defaultdict(list) for c in CONDITIONS}
    jobs: dict[str, list[Path]] = defaultdict(list)
    for job in sorted({p.parent.parent for p in multirun.glob("*/checkpoints/ckpt-*.pt")}):  # a job has several
        agent = job_agent(job)
        policy, _ = checkpoint_policy(job / "checkpoints" / (BEST if best else ""))
        for condition, env in CONDITIONS.items():
            results[condition][agent].append(summary(evaluate(policy, **env)))
        jobs[agent].append(job)
    lines: list[str] = []
    for condition, env in CONDITIONS.items():
        reference = summary(evaluate(kinematic_policy(), **env))
        lines += [f"### {condition}", "", *table(results[condition], reference), ""]
    for agent, dirs in jobs.items():
        learning_curves(dirs, out / f"learning_curves_{agent}.png")
    path = out / ("comparison_best.md" if best else "comparison.md")
    path.write_text("\n".join(lines))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("multirun", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/results"))
    parser.add_argument("--best", action="store_true", help="each run's best-policy.pt instead of its last checkpoint")
    args = parser.parse_args()
    print(compare(args.multirun, args.out, args.best).read_text())


if __name__ == "__main__":
    main()
