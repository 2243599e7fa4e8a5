"""What the discounted objective pays for, from the study's run summaries alone.

The evaluations after each run's first all-lap one (policies that can drive) are binned by their
mean speed. Per bin, measured: the share that lapped >= 11 of 12, the per-step probability of
leaving the road p (failed drives / steps driven) and the reward per step r. The value of driving
on like that, a step ending the episode with probability p, is

    V = (r - p * crash_penalty) / (1 - gamma * (1 - p))

for each discount and crash penalty asked. The bin with the highest V is the speed the objective
prefers; where that bin laps >= 11 less often than the holding target asks, a policy creeping
towards it is optimising its objective, not falling apart. A model: p and r are those of the
policies the runs made at that speed, not of the best policy at each speed.

    python -m actors.evaluation.speed_tradeoff docs/results/levers docs/results/before-bound docs/results/runs \\
        --gammas 0.99 0.995 0.999 --penalties 0 10 300 --out docs/results/speed-tradeoff.md
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from actors.evaluation.compare import staying_good


def bins(records: list[dict], width: float = 0.5) -> dict[float, dict]:
    """Per speed bin (its lower edge, m/s) of the later evaluations: counts, p and r."""
    out: dict[float, dict] = {}
    for record in records:
        good = staying_good(record)
        laps, n = good["laps_per_evaluation"], len(record["evaluations"][0]["drives"]) if record["evaluations"] else 12
        start = len(laps) - good["evaluations_after"]  # staying_good's "later": after the first all-lap one
        for e, lapped in zip(record["evaluations"][start:], laps[start:], strict=True):
            b = out.setdefault(
                round(math.floor(e["mean"]["average_speed"] / width) * width, 3),
                {"evaluations": 0, "with_11": 0, "failures": 0, "steps": 0.0, "reward": 0.0},
            )
            steps = sum(d["episode_length"] for d in e["drives"])
            b["evaluations"] += 1
            b["with_11"] += lapped >= n - 1
            b["failures"] += sum(d["lap_completed"] < 1 for d in e["drives"])
            b["steps"] += steps
            b["reward"] += e["mean"]["reward_per_step"] * steps
    for b in out.values():
        b["p"], b["r"] = b["failures"] / b["steps"], b["reward"] / b["steps"]
    return dict(sorted(out.items()))


def value(b: dict, gamma: float, penalty: float = 0.0) -> float:
    return (b["r"] - b["p"] * penalty) / (1.0 - gamma * (1.0 - b["p"]))


def preferred(
    per_bin: dict[float, dict], gamma: float, penalty: float = 0.0, min_evaluations: int = 10
) -> float | None:
    """The speed bin with the highest value among those with at least `min_evaluations` (None: no such bin)."""
    kept = {s: b for s, b in per_bin.items() if b["evaluations"] >= min_evaluations}
    return max(kept, key=lambda s: value(kept[s], gamma, penalty)) if kept else None


def report(per_bin: dict[float, dict], gammas, penalties, min_evaluations: int, width: float) -> list[str]:
    cases = [(g, p) for g in gammas for p in penalties]
    lines = [
        "| speed (m/s) | evaluations | share >= 11 of 12 | p per step (x 1e-4) | r per step | "
        + " | ".join(f"V (gamma {g}, penalty {p:g})" for g, p in cases)
        + " |",
        "|" + " --- |" * (5 + len(cases)),
    ]
    for s, b in per_bin.items():
        lines.append(
            f"| {s:.1f}-{s + width:.1f} | {b['evaluations']} | {b['with_11'] / b['evaluations']:.0%} | {b['p'] * 1e4:.1f} | "
            f"{b['r']:.3f} | " + " | ".join(f"{value(b, g, p):.1f}" for g, p in cases) + " |"
        )
    lines += ["", f"Preferred speed (highest V among bins with >= {min_evaluations} evaluations):", ""]
    for g, p in cases:
        s = preferred(per_bin, g, p, min_evaluations)
        if s is None:
            lines.append(f"- gamma {g}, crash penalty {p:g}: no bin has {min_evaluations} evaluations")
            continue
        b = per_bin[s]
        lines.append(
            f"- gamma {g}, crash penalty {p:g}: {s:.1f}-{s + width:.1f} m/s, "
            f"where {b['with_11'] / b['evaluations']:.0%} of {b['evaluations']} evaluations lapped >= 11"
        )
    return lines


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dirs", nargs="+", type=Path, help="folders of run summaries (seed*.json, searched below)")
    ap.add_argument("--variant", default="gvf_ddpg", help="only the summaries of this agent variant")
    ap.add_argument("--gammas", nargs="+", type=float, default=[0.99])
    ap.add_argument("--penalties", nargs="+", type=float, default=[0.0])
    ap.add_argument("--width", type=float, default=0.5, help="speed bin width, m/s")
    ap.add_argument("--min-evaluations", type=int, default=10)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    files = sorted({f for d in args.dirs for f in d.glob("**/seed*.json")})
    # a run's summary may be committed twice (the comparison copies its study's runs): count it once
    unique = {f.read_bytes(): f for f in files}
    records = [r for r in (json.loads(b) for b in unique) if r.get("variant") == args.variant]
    if not records:
        raise SystemExit(f"no {args.variant} run summaries (seed*.json) under {', '.join(map(str, args.dirs))}")
    per_bin = bins(records, args.width)
    command = " ".join(["python -m actors.evaluation.speed_tradeoff", *(argv if argv is not None else sys.argv[1:])])
    lines = ["# What the discounted objective pays for", "", f"Built by `{command}`.", ""]
    lines += [
        f"{len(records)} {args.variant} runs; {sum(b['evaluations'] for b in per_bin.values())} later evaluations",
        "",
    ]
    lines += report(per_bin, args.gammas, args.penalties, args.min_evaluations, args.width)
    print("\n".join(lines))
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
