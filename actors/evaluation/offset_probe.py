"""Where along the lap does a policy hold its offset: on the straights, or to one side in the bends?

Each policy drives the 12 test laps (both directions, no noise) and the lane offset is split by
the road's curvature at each step: mean abs(alpha) on the straights, and in the bends the mean
offset towards the outside of the bend (alpha signed against the curvature: positive is outside).
Besides, the side it keeps: mean alpha over every step (positive left), per direction. On the same
roads driven both ways, a policy whose steering is odd under the left-right mirror holds no side
in both directions alike; a steering bias does (it keeps the same side whichever way it drives).
A controller that steers on its offset alone, with no feed-forward of the bend, settles where the
offset makes the steering the bend needs, on the outside, as a proportional controller's
steady-state error; the kinematic controller, with its curvature feed-forward, stays near 0.

    python -m actors.evaluation.offset_probe CKPT [CKPT ...]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from actors.evaluation.evaluate import evaluate
from actors.evaluation.policies import checkpoint_policy

STRAIGHT = 1e-3  # |curvature| (1/m) below which a road sample is straight (the tightest bends: 1/18)


def recording(policy, curvatures: list):
    """`policy`, keeping the road curvature each car was at when it acted (the trace's alpha follows it)."""

    def act(obs: dict, info: dict) -> np.ndarray:
        curvatures.append(np.asarray(info["curvature"], float).copy())
        return policy(obs, info)

    return act


def offsets(policy, **evaluate_kwargs) -> dict:
    """Laps; mean abs(alpha) on the straights; the mean offset to the outside in the bends."""
    curvatures: list = []
    drives = evaluate(recording(policy, curvatures), **evaluate_kwargs)
    k_all = np.stack(curvatures)
    straight, outside, side = [], [], {}
    for i, drive in enumerate(drives):
        alpha = drive["trace"]["alpha"]
        side.setdefault(drive["direction"], []).append(float(np.mean(alpha)))
        k = k_all[: len(alpha), i]
        bend = np.abs(k) >= STRAIGHT
        if (~bend).any():  # a drive that left the road in its first bend has no straight
            straight.append(np.abs(alpha[~bend]).mean())
        if bend.any():
            outside.append((-np.sign(k[bend]) * alpha[bend]).mean())  # curvature > 0 turns left, alpha > 0 is left
    return {
        "laps": int(sum(d["metrics"]["lap_completed"] for d in drives)),
        "straight_abs_alpha": float(np.mean(straight)) if straight else None,
        "bend_outside_alpha": float(np.mean(outside)) if outside else None,
        "mean_abs_alpha": float(np.mean([d["metrics"]["offcenteredness"] for d in drives])),
        "side_alpha": {direction: float(np.mean(v)) for direction, v in side.items()},
    }


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoints", nargs="+", help="learner checkpoints (files, or folders: the newest in each)")
    args = p.parse_args(argv)
    rows = []
    for path in args.checkpoints:
        policy, meta = checkpoint_policy(path)
        rows.append({"checkpoint": meta["path"], "updates": meta["updates"], **offsets(policy)})
        print(json.dumps(rows[-1]))
    return rows


if __name__ == "__main__":
    main()
