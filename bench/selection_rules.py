"""Which evaluation each validation-ranking rule would have selected, and its test laps, over the
eval.jsonl files of finished runs: the measurement behind `common.selection.selection_key`.

    python bench/selection_rules.py RUN_DIR [RUN_DIR ...]     # last line: JSON

Each rule ranks the validation metrics of every evaluation; like the evaluator, the first of
equals is kept. A rule is better when its picks lap more of the test roads.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from common.selection import selected

RULES = {
    "laps_then_reward": lambda v: (v["lap_completed"], v["reward_per_s"]),
    "laps_then_near_out_then_reward": lambda v: (v["lap_completed"], -v["near_out_of_lane"], v["reward_per_s"]),
    "laps_then_abs_alpha_then_reward": lambda v: (v["lap_completed"], -v["offcenteredness"], v["reward_per_s"]),
}


def picks(evaluations: list[dict]) -> dict:
    out = {}
    for name, key in RULES.items():
        best = selected(evaluations, key)
        out[name] = {
            "updates": best["updates"],
            "test_laps": round(best["mean"]["lap_completed"] * len(best["drives"])),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path)
    runs = {}
    for run in parser.parse_args().runs:
        path = run / "eval.jsonl"
        evaluations = (
            [e for e in map(json.loads, path.read_text().splitlines()) if "validation" in e] if path.exists() else []
        )
        if evaluations:
            runs[run.name] = picks(evaluations)
            print(run.name, {k: v["test_laps"] for k, v in runs[run.name].items()})
    totals = {name: sum(r[name]["test_laps"] for r in runs.values()) for name in RULES}
    print(json.dumps({"runs": runs, "total_test_laps": totals, "n_runs": len(runs)}))


if __name__ == "__main__":
    main()
