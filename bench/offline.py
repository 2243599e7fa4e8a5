"""Offline benchmark (issue 14): collection steps/s, and offline updates/s against the bare networks.

Collection: `actors.collect.collect_worker` (one process, `--cars` cars, the random-walk
controller, shards written and hashed) against the same cars and controller stepped without
recording (the peer): `collect_ratio` is what the dataset costs. 100,000 transitions take
100,000 / (steps/s x workers) seconds with one worker per core.

Updates, each against the bare forward/backward of the networks it trains, on the same batch:
- `algorithm2`: `RepresentationTrainer.step` (rho-resampled and uniform draws, the GVF TD step
  with v(s'), the discriminator step) against one forward/backward of the GVFs and g;
- `gvf_bcq`: a BCQ update on a phi table against one forward/backward of its three networks;
- `e2e_bcq`: the same on images (three PilotNet trunks).
Rounds alternate full and bare; medians of the per-round ratios. The last line is one JSON object.

    python bench/offline.py [--rounds R] [--threads N]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time

import numpy as np
import torch
from tensordict import TensorDict

from actors.collect import collect_worker
from actors.controllers.random_walk import for_lane_drive, lane_drive_pose
from actors.envs.lane_drive import LaneDriveVectorEnv
from actors.envs.sim import road_map
from actors.envs.tracks import track_names
from common.bcq_networks import E2E_STATE_DIM
from common.cli import compose_run
from common.config.env import EnvConfig
from common.dataset import Dataset
from learner.bcq import make_bcq
from learner.core import _obs
from learner.offline import RepresentationTrainer
from learner.replay import expand

ENV = {"track": "train", "direction": "random", "random_start": True}


def bare_drive(steps: int, cars: int) -> float:
    """Steps/s of the cars and controllers alone (no recording)."""
    rng = np.random.default_rng(0)
    env = LaneDriveVectorEnv(cars, **ENV)
    env.reset(seed=list(range(cars)))
    ctrls = [for_lane_drive(env, rng, i) for i in range(cars)]
    start = time.perf_counter()
    for _ in range(steps // cars):
        _, _, term, trunc, _ = env.step(np.stack([c.act(lane_drive_pose(env, i)) for i, c in enumerate(ctrls)]))
        for i in np.flatnonzero(term | trunc):
            ctrls[i] = for_lane_drive(env, rng, int(i))
    return steps / (time.perf_counter() - start)


def collection(steps: int, cars: int, rounds: int) -> dict:
    for name in track_names("train"):  # every camera map drawn once, outside the timing of either side
        road_map(name, EnvConfig().lane_width, (0.0, 0.0, 0.0))
    full, bare = [], []
    for r in range(rounds):
        with tempfile.TemporaryDirectory() as root:
            start = time.perf_counter()
            collect_worker(root, seed=r, worker=0, quota=steps, cars=cars, shard_size=1000, env_kwargs=ENV)
            full.append(steps / (time.perf_counter() - start))
        bare.append(bare_drive(steps, cars))
    return {
        "collect_steps_per_s": round(statistics.median(full), 1),
        "drive_steps_per_s": round(statistics.median(bare), 1),
        "collect_ratio": round(statistics.median(f / b for f, b in zip(full, bare)), 3),
    }


def timed(fn, n: int) -> float:
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return n / (time.perf_counter() - start)


def bare_step(modules: list[torch.nn.Module], loss_fn) -> None:
    for m in modules:
        m.zero_grad(set_to_none=True)
    loss_fn().backward()


def compare(full, bare, rounds: int, n: int) -> dict:
    fr, br = [], []
    for _ in range(rounds):
        fr.append(timed(full, n))
        br.append(timed(bare, n))
    return {
        "updates_per_s": round(statistics.median(fr), 2),
        "bare_per_s": round(statistics.median(br), 2),
        "ratio": round(statistics.median(f / b for f, b in zip(fr, br)), 3),
    }


def updates(dataset: Dataset, rounds: int, n: int) -> dict:
    cfg = compose_run(["scale=small"])
    agent, scale = cfg.agent, cfg.scale
    trainer = RepresentationTrainer(agent, scale, dataset, updates=10**6, loading="full", seed=0)
    trainer.step()  # loads everything, warm start
    core = trainer.core
    batch = expand(core.replay.sample_uniform(scale.batch_size))
    gvf, g = core.nets.gvf, core.nets.behaviour

    def bare_rep():
        bare_step([gvf, g], lambda: gvf(*_obs(batch)).square().mean() + g(*_obs(batch), batch["action"]).mean())

    out = {"algorithm2": compare(trainer.step, bare_rep, rounds, n)}
    b = scale.batch_size
    for name, dim, channels in (
        ("gvf_bcq", gvf.n_predictions + 3, None),
        ("e2e_bcq", E2E_STATE_DIM, scale.conv_channels),
    ):
        bcq = make_bcq(dim if channels is None else 0, image_channels=channels)
        scale_obs = 255.0 if channels else 1.0
        td = TensorDict(
            {
                "observation": torch.rand(b, dim) * scale_obs,
                "action": torch.rand(b, 2) * 2 - 1,
                "next": {
                    "observation": torch.rand(b, dim) * scale_obs,
                    "reward": torch.rand(b, 1),
                    "done": torch.zeros(b, 1, dtype=torch.bool),
                    "terminated": torch.zeros(b, 1, dtype=torch.bool),
                },
            },
            [b],
        )
        loss = bcq.loss
        s, a = td["observation"], td["action"]
        nets = [loss.vae_network, loss.actor_network, loss.qvalue_network]

        def bare_bcq(s=s, a=a, loss=loss, nets=nets):
            def total():
                recon, _, _ = loss.vae_network(s, a)
                return recon.mean() + loss.actor_network(s, a).mean() + loss.qvalue_network(s, a).mean()

            bare_step(nets, total)

        out[name] = compare(
            lambda bcq=bcq, td=td: bcq.update(td), bare_bcq, rounds, max(2, n // (8 if channels else 1))
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--steps", type=int, default=4000, help="collection steps per round")
    parser.add_argument("--cars", type=int, default=4)
    parser.add_argument("--updates", type=int, default=40, help="updates per timed round")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    result = {"bench": "offline", "threads": args.threads, "cars": args.cars}
    result.update(collection(args.steps, args.cars, args.rounds))
    result["minutes_for_100k_with_2_workers"] = round(100_000 / (2 * result["collect_steps_per_s"]) / 60, 1)
    with tempfile.TemporaryDirectory() as root:
        collect_worker(root, seed=99, worker=0, quota=3000, cars=args.cars, shard_size=1000, env_kwargs=ENV)
        result.update(updates(Dataset.open(root), args.rounds, args.updates))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
