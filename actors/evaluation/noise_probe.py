"""How much of the lane offset does the exploration noise itself cause?

A policy (a checkpoint's, or the kinematic controller) drives every test road in both directions
with OU noise added to its actions, as an actor explores, once per (theta, sigma) setting, and
the drive's steering noise is correlated with alpha at the same step. The paper's OU (theta 1,
dt 0.01) wanders with a 10-s correlation time: a steering bias held that long moves the car to an
offset that holds it, so in the replay the noise of a step goes with the offset of that step and
the critic cannot tell the action's effect from the state's (its dQ/d(steering) off the centre is
then confounded). With theta * dt = 1 each step's noise is new (white) and that correlation is gone.

    python -m actors.evaluation.noise_probe CKPT --settings 1:0.1 100:0.75
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from actors.evaluation.evaluate import evaluate
from actors.evaluation.policies import checkpoint_policy, kinematic_policy
from actors.exploration import OrnsteinUhlenbeck
from common.config.run import ActorConfig

DT = ActorConfig.ou_dt  # the OU step the actors take by default


def noisy(policy, theta: float, sigma: float, seed: int, record: list):
    """`policy` with OU(theta, sigma) noise per car added to its actions (clipped as the actors
    clip); each step's steering noise appended to `record`."""
    noise: list[OrnsteinUhlenbeck] = []

    def act(obs: dict, info: dict) -> np.ndarray:
        if not noise:  # one process per car of the batch
            noise.append(OrnsteinUhlenbeck(len(obs["speed"]), 2, theta=theta, sigma=sigma, dt=DT, seed=seed))
        n = noise[0].sample()
        record.append(n[:, 0])
        return np.clip(policy(obs, info) + n, -1.0, 1.0)

    return act


def probe(policy, theta: float, sigma: float, seed: int = 0, **evaluate_kwargs) -> dict:
    """Drives with OU(theta, sigma) noise: per drive corr(steering noise, alpha), laps, mean |alpha|."""
    record: list = []
    drives = evaluate(noisy(policy, theta, sigma, seed, record), **evaluate_kwargs)
    steer = np.stack(record)  # (steps, drives): the noise of the action that led to trace step t
    corr = [
        float(np.corrcoef(steer[: len(d["trace"]["alpha"]), i], d["trace"]["alpha"])[0, 1])
        for i, d in enumerate(drives)
    ]
    return {
        "theta": theta,
        "sigma": sigma,
        "noise_std": float(steer.std()),
        "corr_noise_alpha": float(np.mean(corr)),
        "corr_per_drive": [round(c, 3) for c in corr],
        "laps": int(sum(d["metrics"]["lap_completed"] for d in drives)),
        "mean_abs_alpha": float(np.mean([d["metrics"]["offcenteredness"] for d in drives])),
    }


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", help="a learner checkpoint (file or folder), or 'kinematic'")
    p.add_argument("--settings", nargs="+", default=["1:0.1", "100:0.75"], help="theta:sigma pairs (dt 0.01)")
    args = p.parse_args(argv)
    policy = kinematic_policy() if args.checkpoint == "kinematic" else checkpoint_policy(args.checkpoint)[0]
    rows = []
    for setting in args.settings:
        theta, sigma = (float(x) for x in setting.split(":"))
        rows.append(probe(policy, theta, sigma))
        print(json.dumps(rows[-1]))
    return rows


if __name__ == "__main__":
    main()
