"""Learner step benchmark (issue 3): updates/s of the full GVF-DDPG step at batch 128, beside
the bare forward/backward of the same networks on the same batch, measured in the same run.

Full step: insert `batch / samples_per_insert` new transitions (rho by the discriminator,
Algorithm 1 lines 8-10) + `LearningCore.update()` (rho-resampled and uniform sampling,
GVF TD step, discriminator step, DDPG step, optimisers, target update).
Bare step: one forward and one backward of each trained network (GVF, discriminator,
actor, critic) on one fixed batch, no optimiser step.
`network_ratio` also counts, on the bare side, the three forward passes without gradient
that the algorithm itself needs (v(s') for the TD target, phi(s) and phi(s') for DDPG):
full / (bare + those) is the overhead of everything that is not network arithmetic.

Timing alternates full and bare in many short rounds and reports medians over rounds (of
rates, and of the per-round ratios), so that load from other processes hits both alike.
The last line printed is one JSON object.

    python bench/learner_step.py [--device cpu|cuda] [--threads N] [--rounds R]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import torch
from tensordict import TensorDict

from common.cli import compose_run
from common.config.agent import AgentConfig, ScaleConfig
from common.networks import phi
from learner.core import LearningCore
from learner.replay import expand

# the scales of conf/scale/ themselves (common.cli.compose_run), not copies of them
SCALES = {name: compose_run([f"scale={name}"]).scale for name in ("small", "paper")}
SAMPLES_PER_INSERT = 8  # the learner service's default rate limit


def random_transitions(n: int, generator: torch.Generator) -> TensorDict:
    def u(*shape):
        return torch.rand(*shape, generator=generator) * 2 - 1

    def frames():
        return torch.randint(0, 256, (n, 2, 64, 128), generator=generator, dtype=torch.uint8)

    return TensorDict(
        {
            "image": frames(),
            "speed": torch.rand(n, 1, generator=generator),
            "last_action": u(n, 2),
            "alpha": u(n, 1),
            "beta": u(n, 1),
            "action": u(n, 2),
            "next": {
                "image": frames(),
                "speed": torch.rand(n, 1, generator=generator),
                "alpha": u(n, 1),
                "beta": u(n, 1),
                "reward": u(n, 1),
                "terminated": torch.rand(n, 1, generator=generator) < 0.01,
                "truncated": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        batch_size=[n],
    )


class Bench:
    def __init__(self, scale: ScaleConfig, device: str, fill: int):
        agent = AgentConfig(name="gvf_ddpg", metrics_every=10**9)
        self.core = LearningCore(agent, scale, device=device, buffer_size=fill, warmup=1)
        self.device = device
        g = torch.Generator().manual_seed(0)
        for _ in range(fill // 256):
            self.core.add(random_transitions(256, g))
        self.inserts = [random_transitions(scale.batch_size // SAMPLES_PER_INSERT, g).to(device) for _ in range(8)]
        n = scale.batch_size
        self.batch = expand(self.core.replay.sample_uniform(n)).to(device)
        nets = self.core.nets
        with torch.no_grad():
            v = nets.gvf(self.batch["image"], self.batch["speed"], self.batch["last_action"])
        self.phi = phi(v, self.batch["speed"], self.batch["last_action"])
        self.calls = 0

    def sync(self) -> None:
        if self.device.startswith("cuda"):
            torch.cuda.synchronize()

    def full(self) -> None:
        self.core.add(self.inserts[self.calls % len(self.inserts)])
        self.core.update()
        self.calls += 1

    def bare(self, with_forwards: bool = False) -> None:
        nets, b = self.core.nets, self.batch
        obs = (b["image"], b["speed"], b["last_action"])
        for module in nets.modules().values():
            module.zero_grad(set_to_none=True)
        loss = (
            nets.gvf(*obs).mean()
            + nets.behaviour(*obs, b["action"]).mean()
            + nets.actor(self.phi).mean()
            + nets.critic(self.phi, b["action"]).mean()
        )
        loss.backward()
        if with_forwards:  # the forward passes without gradient the algorithm needs
            with torch.no_grad():
                for _ in range(3):
                    nets.gvf(*obs)

    def rate(self, step, n: int) -> float:
        self.sync()
        start = time.perf_counter()
        for _ in range(n):
            step()
        self.sync()
        return n / (time.perf_counter() - start)

    def run(self, rounds: int, per_round: int) -> dict[str, float]:
        for step in (self.full, self.bare):  # warm-up: allocator, kernels, Adam state
            self.rate(step, 2)
        full, bare, network = [], [], []
        for _ in range(rounds):
            full.append(self.rate(self.full, per_round))
            bare.append(self.rate(self.bare, per_round))
            network.append(self.rate(lambda: self.bare(with_forwards=True), per_round))
        ratios = [b / f for f, b in zip(full, bare)]
        network_ratios = [n / f for f, n in zip(full, network)]
        return {
            "updates_per_s": statistics.median(full),
            "bare_per_s": statistics.median(bare),
            "overhead_ratio": statistics.median(ratios),
            "network_ratio": statistics.median(network_ratios),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    parser.add_argument("--rounds", type=int, default=15)
    args = parser.parse_args()
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: no CUDA device available")
    torch.set_num_threads(args.threads)
    per_round = {"small": 2, "paper": 1} if args.device == "cpu" else {"small": 10, "paper": 10}
    result: dict[str, object] = {
        "device": args.device,
        "threads": args.threads,
        "batch_size": 128,
        "inserts_per_update": 128 // SAMPLES_PER_INSERT,
    }
    if args.device == "cuda":
        result["gpu"] = torch.cuda.get_device_name()
    started = time.perf_counter()
    for name, scale in SCALES.items():
        stats = Bench(scale, args.device, fill=1024).run(args.rounds, per_round[name])
        print(f"{name}: " + ", ".join(f"{k} {v:.3f}" for k, v in stats.items()), flush=True)
        for key, value in stats.items():
            result[f"{key}_{name}"] = round(value, 3)
    result["target_overhead_ratio"] = 1.5
    result["meets_target"] = result["overhead_ratio_paper"] <= 1.5
    result["seconds"] = round(time.perf_counter() - started, 1)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
