"""Which evaluation each validation-ranking rule would have selected, and how it drove the test
roads, over finished runs: the measurement behind `common.selection.selection_key`.

    python bench/selection_rules.py RUN_DIR|SUMMARY.json [...]     # last line: JSON

A run is a run folder (its eval.jsonl) or a study summary (docs/results/**/seedN.json, whose
evaluations carry the same validation and test means). Each rule ranks the validation metrics of
every evaluation; like the evaluator, the first of equals is kept. A rule is better when its picks
lap more of the test roads, more of them lap all but one (>= 11 of 12), and more lap that way
centred (near-out-of-lane <= 0.01 and mean abs(alpha) <= 0.1, issue 11's bar). `oracle_centred`
counts the runs where any evaluation reached that bar: the most a rule could pick.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from common.selection import selected, selection_key

RULES = {
    "laps_then_reward": lambda v: (v["lap_completed"], v["reward_per_s"]),
    "laps_then_near_out_then_reward": lambda v: (v["lap_completed"], -v["near_out_of_lane"], v["reward_per_s"]),
    "laps_then_abs_alpha_then_reward": lambda v: (v["lap_completed"], -v["offcenteredness"], v["reward_per_s"]),
    "laps_then_near_out_then_abs_alpha": selection_key,  # the evaluator's
}


def laps_on_test(evaluation: dict) -> int:
    return round(evaluation["mean"]["lap_completed"] * len(evaluation["drives"]))


def all_but_one(evaluation: dict) -> bool:
    return laps_on_test(evaluation) >= len(evaluation["drives"]) - 1


def centred(evaluation: dict) -> bool:
    """Issue 11's bar on the test roads: >= 11 of 12 laps, near-out <= 0.01, mean abs(alpha) <= 0.1."""
    m = evaluation["mean"]
    return all_but_one(evaluation) and m["near_out_of_lane"] <= 0.01 and m["offcenteredness"] <= 0.1


def picks(evaluations: list[dict]) -> dict:
    out = {}
    for name, key in RULES.items():
        best = selected(evaluations, key)
        out[name] = {
            "updates": best["updates"],
            "test_laps": laps_on_test(best),
            "laps_all_but_one": all_but_one(best),
            "centred": centred(best),
            "reward_per_s": best["mean"]["reward_per_s"],
        }
    return out


def load(source: Path) -> list[dict]:
    """The evaluations with a validation of a run folder or a study summary ([] if it has none)."""
    if source.is_dir():
        path = source / "eval.jsonl"
        records = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    else:
        data = json.loads(source.read_text())
        records = data.get("evaluations", []) if isinstance(data, dict) else []
    return [e for e in records if isinstance(e, dict) and e.get("validation") and e.get("drives") and "mean" in e]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--quiet", action="store_true", help="only the JSON line")
    args = parser.parse_args()
    runs, oracle = {}, 0
    for source in args.runs:
        evaluations = load(source)
        if not evaluations:
            continue
        name = source.name if source.is_dir() else str(source)
        runs[name] = picks(evaluations)
        oracle += any(map(centred, evaluations))
        if not args.quiet:
            print(name, {k: v["test_laps"] for k, v in runs[name].items()})
    n = len(runs)
    totals = {
        rule: {
            "test_laps": sum(r[rule]["test_laps"] for r in runs.values()),
            "laps_all_but_one": sum(r[rule]["laps_all_but_one"] for r in runs.values()),
            "centred": sum(r[rule]["centred"] for r in runs.values()),
            "mean_reward_per_s": round(sum(r[rule]["reward_per_s"] for r in runs.values()) / max(n, 1), 3),
        }
        for rule in RULES
    }
    print(json.dumps({"runs": runs, "totals": totals, "oracle_centred": oracle, "n_runs": n}))


if __name__ == "__main__":
    main()
