"""How the periodic evaluator ranks validations, shared by the evaluator that keeps
checkpoints/best-policy.pt and the live view that names it (common.progress), so both pick the
same evaluation."""

from __future__ import annotations

BEST = "best-policy.pt"
"""File name, in a run's checkpoints folder, of the policy of the best validation so far."""

RANKING = "laps, near-out-of-lane, mean abs(alpha), reward per second"
"""`selection_key` in words: study summaries record it, so the ones made under an earlier ranking
("laps, near-out-of-lane, reward per second" until 2026-12-07) can be told apart."""


def selection_key(mean: dict) -> tuple:
    """How validations rank: most laps, then the least time near the lane's edge, then the least mean
    abs(alpha), then reward per second. Ranking by reward per second right after laps picked the
    fastest of the lapping policies, the riskiest (run C, docs/results.md: all 12 validation laps but
    8 of 12 test laps). Over 233 committed study summaries (bench/selection_rules.py,
    docs/results/levers/selection-rules-summaries.json) the abs(alpha) tie-break picked a policy that
    lapped >= 11 test laps centred in 142 (reward per second there: 103; the best any rule could: 154)."""
    return (
        mean["lap_completed"],
        -mean.get("near_out_of_lane", 0.0),
        -mean.get("offcenteredness", 0.0),
        mean["reward_per_s"],
    )


def better(mean: dict, best: dict | None) -> bool:
    """Strictly better than `best` by `selection_key` (so the first of equals is kept)."""
    return best is None or selection_key(mean) > selection_key(best)


def selected(records: list[dict], key=selection_key) -> dict | None:
    """The eval.jsonl record whose validation ranks first by `key` (the first of equals): with the
    default key, the one whose policy best-policy.pt holds; records without a validation are
    passed over."""
    best = None
    for record in records:
        v = record.get("validation")
        if v and (best is None or key(v) > key(best["validation"])):
            best = record
    return best
