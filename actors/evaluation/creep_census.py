"""How often runs creep, and whether the seed decides it: over committed study summaries, a run
"crept" when its test drives averaged more than `--speed` m/s over the evaluations in the early
window (`--window`, updates), the speed at which the policy leaves the 18 m bends before it laps
(docs/results.md "Why the policy swung"). Per seed: the runs, how many crept, how many of those
lapped all 12 later. If the seed decided it, a seed's runs would all creep or none would.
Also per seed: how many runs lapped all 12 by `--by` updates (how early the first laps came).

    python -m actors.evaluation.creep_census docs/results/runs docs/results/levers   # last line: JSON
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path


def crept(evaluations: list[dict], speed: float, window: tuple[int, int]) -> bool | None:
    """Whether the mean test speed in the window exceeds `speed`; None without an evaluation there."""
    speeds = [e["mean"]["average_speed"] for e in evaluations if window[0] <= e["updates"] <= window[1]]
    return sum(speeds) / len(speeds) > speed if speeds else None


def lapped_all(evaluations: list[dict], by: float = float("inf")) -> bool:
    """Whether an evaluation at or before `by` updates lapped all 12."""
    return any(e["mean"]["lap_completed"] >= 0.999 and e["updates"] <= by for e in evaluations)


def summaries(roots: list[Path], variant: str):
    """Every study summary of `variant` under the roots."""
    for root in roots:
        for path in sorted(root.rglob("seed*.json")):
            try:
                data = json.loads(path.read_text())
            except (OSError, ValueError):
                continue
            if isinstance(data, dict) and data.get("variant") == variant and data.get("evaluations"):
                yield data


def census(roots: list[Path], variant: str, speed: float, window: tuple[int, int], by: int = 5000) -> dict:
    seeds: dict[int, dict] = defaultdict(lambda: {"runs": 0, "crept": 0, "crept_then_lapped": 0, "lapped_by": 0})
    for data in summaries(roots, variant):
        evaluations = [e for e in data["evaluations"] if isinstance(e, dict) and "mean" in e]
        c = crept(evaluations, speed, window)
        if c is None:
            continue
        row = seeds[int(data["seed"])]
        row["runs"] += 1
        row["crept"] += c
        row["crept_then_lapped"] += c and lapped_all(evaluations)
        row["lapped_by"] += lapped_all(evaluations, by)
    runs = sum(r["runs"] for r in seeds.values())
    n_crept = sum(r["crept"] for r in seeds.values())
    mixed = sum(0 < r["crept"] < r["runs"] for r in seeds.values())
    return {
        "variant": variant,
        "speed": speed,
        "window": list(window),
        "runs": runs,
        "crept": n_crept,
        "crept_then_lapped": sum(r["crept_then_lapped"] for r in seeds.values()),
        "by": by,
        "lapped_by": sum(r["lapped_by"] for r in seeds.values()),
        "seeds_with_both": mixed,
        "seeds_with_2_or_more_runs": sum(r["runs"] >= 2 for r in seeds.values()),
        "per_seed": {str(k): v for k, v in sorted(seeds.items())},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("roots", nargs="+", type=Path)
    parser.add_argument("--variant", default="gvf_ddpg")
    parser.add_argument("--speed", type=float, default=14.8)
    parser.add_argument("--window", type=int, nargs=2, default=(2000, 3500))
    parser.add_argument("--by", type=int, default=5000, help="count runs lapping all 12 by this many updates")
    args = parser.parse_args()
    result = census(args.roots, args.variant, args.speed, tuple(args.window), args.by)
    for seed, row in result["per_seed"].items():
        print(
            f"seed {seed}: {row['crept']} of {row['runs']} crept, {row['crept_then_lapped']} of them lapped all 12"
            f" later; {row['lapped_by']} lapped all 12 by {args.by} updates"
        )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
