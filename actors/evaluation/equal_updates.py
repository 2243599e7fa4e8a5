"""Variants compared at equal learner updates, from the study's run summaries alone: a wall-clock
budget buys each variant (and each day's machine) a different number of updates, so every run is
cut at the same update count and its evaluations after the cut are dropped (a run that ended
before the cut counts as it ended).

    python -m actors.evaluation.equal_updates --cut 8500 11000 \\
        --runs "GVF-DDPG=docs/results/runs/gvf_ddpg" "DDPG-Image=docs/results/runs/ddpg_image" \\
        --out docs/results/equal-updates.md
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from actors.evaluation.compare import staying_good


def cut(record: dict, updates: int) -> dict:
    """The run as it stood at `updates`: its evaluations up to there (the final policies dropped)."""
    return {**record, "evaluations": [e for e in record["evaluations"] if e["updates"] <= updates], "last": None}


def at_cut(records: list[dict], updates: int) -> dict:
    """Per run the test laps of its last evaluation and the mean of its last 3; pooled over the runs,
    the evaluations after each run's first all-lap one and how many of them lapped >= 11 of 12."""
    good = [staying_good(cut(r, updates)) for r in records]
    laps = [g["laps_per_evaluation"] for g in good if g["laps_per_evaluation"]]
    return {
        "runs": len(laps),
        "last_laps": [x[-1] for x in laps],
        "last3_fraction": float(np.mean([np.mean(x[-3:]) / 12 for x in laps])) if laps else None,
        "later": sum(g["evaluations_after"] for g in good),
        "later_with_11": sum(g["after_with_11"] for g in good),
    }


def table(groups: dict[str, list[dict]], cuts: list[int]) -> list[str]:
    lines = [
        "| cut at (updates) | variant (runs) | test laps at the last evaluation, of 12 (mean fraction) | mean of the last 3 evaluations | later evaluations >= 11, pooled |",
        "|" + " --- |" * 5,
    ]
    for c in cuts:
        for name, records in groups.items():
            a = at_cut(records, c)
            if not a["runs"]:
                continue
            share = f"{a['later_with_11']} of {a['later']}" + (
                f" ({a['later_with_11'] / a['later']:.0%})" if a["later"] else ""
            )
            lines.append(
                f"| {c:,} | {name} ({a['runs']}) | {', '.join(map(str, a['last_laps']))} ({np.mean(a['last_laps']) / 12:.2f}) "
                f"| {a['last3_fraction']:.2f} | {share} |"
            )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cut", type=int, nargs="+", required=True, help="learner update counts to cut every run at")
    parser.add_argument("--runs", nargs="+", required=True, help="NAME=DIR: a folder of seed<k>.json summaries")
    parser.add_argument("--out", type=Path, default=None, help="write the table here (markdown) as well")
    args = parser.parse_args()
    groups = {}
    for spec in args.runs:
        name, sep, folder = spec.partition("=")
        if not sep:
            parser.error(f"--runs takes NAME=DIR, got {spec!r}")
        groups[name] = [json.loads(p.read_text()) for p in sorted(Path(folder).glob("seed*.json"))]
        if not groups[name]:
            parser.error(f"no seed*.json summaries in {folder}")
    lines = table(groups, sorted(args.cut))
    print("\n".join(lines))
    if args.out is not None:
        args.out.write_text(
            "# Variants at equal learner updates\n\nBuilt by `python -m actors.evaluation.equal_updates` from the run "
            "summaries; a run that ended before a cut counts as it ended. Runs:\n\n"
            + "".join(f"- {spec.partition('=')[0]}: `{spec.partition('=')[2]}`\n" for spec in args.runs)
            + "\n"
            + "\n".join(lines)
            + "\n"
        )


if __name__ == "__main__":
    main()
