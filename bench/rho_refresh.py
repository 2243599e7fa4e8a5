"""rho from an untrained discriminator, before and after the fix: the same LaneDrive data
(kinematic controller + OU noise) streamed into the learning core as in Algorithm 1, once with
rho fixed at insert (the paper; the warm-up's rho then comes from an untrained g) and once with
g trained on the warm-up data, every rho recomputed, and again every K updates (the default).

Reports rho_bar over the run, the share of the GVF sampling mass held by the warm-up block,
and the GVFs' RMSE against Monte Carlo returns under tau (actors/evaluation/gvf_truth.py) from
held-out visited states, relative to the best constant. Last line: one JSON object.

    python bench/rho_refresh.py [--updates 1500] [--warmup 1000]
"""

from __future__ import annotations

import argparse
import json

import torch

from actors.evaluation.gvf_truth import collect, tau_returns
from common.cli import compose_run
from common.config.agent import AgentConfig
from learner.core import LearningCore

GAMMAS = [0.0, 0.5, 0.9, 0.95, 0.97]
SMALL = compose_run(["scale=small"]).scale  # conf/scale/small.yaml itself


def run(setting: dict, data, obs, truth, updates: int, warmup: int, ratio: float) -> dict:
    agent = AgentConfig(name="gvf_ddpg", metrics_every=10**9, **setting)
    core = LearningCore(agent, SMALL, seed=0, buffer_size=len(data), warmup=warmup)
    curve = []
    for chunk in data.split(160):  # recorded order, as actors stream it
        core.add(chunk)
        while core.ready and core.updates < (len(core.replay) - warmup) / ratio + 1:
            core.update()
            if core.updates % 100 == 0:
                curve.append([core.updates, round(core.replay.rho_bar, 3)])
    while core.updates < updates:
        core.update()
        if core.updates % 100 == 0:
            curve.append([core.updates, round(core.replay.rho_bar, 3)])
    rho = core.replay.rho[: len(core.replay)]
    with torch.no_grad():
        predictions = core.nets.gvf(obs["image"], obs["speed"], obs["last_action"])
    rmse = (predictions - truth).square().mean(0).sqrt()
    constant = (truth - truth.mean(0)).square().mean(0).sqrt()
    rel = (rmse / constant).reshape(2, len(GAMMAS))
    return {
        "rho_bar": curve,
        "warmup_mass_share": round(float(rho[:warmup].sum() / rho.sum()), 3),
        "warmup_share_of_items": round(warmup / len(rho), 3),
        "rmse_over_constant_alpha": [round(float(x), 3) for x in rel[0]],
        "rmse_over_constant_beta": [round(float(x), 3) for x in rel[1]],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--updates", type=int, default=1500)
    parser.add_argument("--warmup", type=int, default=1000)
    parser.add_argument("--ratio", type=float, default=2.0, help="transitions inserted per update while streaming")
    parser.add_argument("--sigma", type=float, default=0.5, help="OU noise of the behaviour")
    args = parser.parse_args()
    torch.set_num_threads(2)
    data = collect(8, 500, seed=0, sigma=args.sigma)
    data = data.reshape(8, 500).transpose(0, 1).reshape(-1)  # time-major: 8 cars side by side, as they arrive
    out = {"gammas": GAMMAS, "transitions": len(data), "warmup": args.warmup, "updates": args.updates}
    for terminal in ("absorbing",):
        obs, truth = tau_returns(80, GAMMAS, seed=7, sigma=args.sigma, terminal=terminal)
        for name, setting in (
            ("fixed_at_insert", dict(behaviour_warmup_updates=0, rho_refresh_every=0)),
            ("warm_start_and_refresh", {}),
        ):
            out[name] = run(
                {**setting, "gvf_terminal": terminal}, data, obs, truth, args.updates, args.warmup, args.ratio
            )
            print(name, json.dumps(out[name]), flush=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
