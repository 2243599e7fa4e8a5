"""The learner's diagnostics along a run, from its TensorBoard events, binned by updates: small
enough for a study summary (`study.summarize`), so that a committed run says not only how it drove
but what its critic and actor did meanwhile (e.g. `diag/critic_to_centre` against
`diag/steer_to_centre`: does the actor follow its critic back to the lane's centre?).

    python -m actors.evaluation.learner_curves runs/crash-penalty-memory/gvf_ddpg-seed3
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

# train/q_ takes the minibatch's Q mean, min, max and target mean: a Q range that sinks as a whole
# is a critic drifting from the returns, which the mean alone does not tell from a wider spread
TAGS = ("diag/", "train/q_", "losses/actor", "losses/critic", "losses/td")
EVERY = 500  # updates per bin: the periodic evaluations' spacing


def learner_curves(tb_dir: Path, every: int = EVERY, tags=TAGS) -> dict[str, list]:
    """{"updates": bin ends, tag: mean per bin (None where the bin has no value)} of the scalars
    whose name starts with one of `tags` (the run log writes the latest metrics at its own pace: a
    report logged twice weighs twice, as the time it stood)."""
    if not Path(tb_dir).is_dir():
        return {}
    events = EventAccumulator(str(tb_dir), size_guidance={"scalars": 0})
    events.Reload()
    bins: dict[str, dict[int, list[float]]] = {}
    for tag in events.Tags()["scalars"]:
        if not tag.startswith(tags):
            continue
        per_bin = defaultdict(list)
        for event in events.Scalars(tag):
            per_bin[-(-event.step // every) * every].append(event.value)
        bins[tag] = per_bin
    ends = sorted({end for per_bin in bins.values() for end in per_bin})
    out: dict[str, list] = {"updates": ends}
    for tag, per_bin in sorted(bins.items()):
        out[tag] = [round(sum(v) / len(v), 5) if (v := per_bin.get(end)) else None for end in ends]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a run folder (holding tb/) or a study summary JSON")
    parser.add_argument("--tags", nargs="*", default=["diag/critic_to_centre", "diag/steer_to_centre"])
    args = parser.parse_args()
    if args.run.suffix == ".json":
        curves = json.loads(args.run.read_text()).get("learner", {})
    else:
        curves = learner_curves(args.run / "tb")
    print("| updates | " + " | ".join(args.tags) + " |")
    print("| --- " * (len(args.tags) + 1) + "|")
    for i, end in enumerate(curves.get("updates", [])):
        cells = [curves.get(tag, [None] * (i + 1))[i] for tag in args.tags]
        print(f"| {end} | " + " | ".join("-" if c is None else f"{c:.3f}" for c in cells) + " |")


if __name__ == "__main__":
    main()
