"""n-step benchmark: what `scale.n_step` costs the learner, as updates/s of the full GVF-DDPG
update with 5-step returns against the same update with the paper's 1-step target, measured in
the same run (alternating rounds, medians), on the small scale's networks.

Both cores hold the same replay of random transitions in chunks of 32 (the actors' chunk
length); the 5-step one also computes the n-step columns at insert and reads each minibatch's
bootstrap states from the replay (learner.nstep). Limit: >= 0.9x of the 1-step rate.
The last line printed is one JSON object.

    python bench/nstep.py [--threads N] [--rounds R] [--n 5]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import sys
import time
from pathlib import Path

import torch

# run as a script, bench/ comes first on sys.path: the repository root goes there instead
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

from bench.learner_step import SAMPLES_PER_INSERT, SCALES, random_transitions  # noqa: E402
from common.config.agent import AgentConfig  # noqa: E402
from learner.core import LearningCore  # noqa: E402
from learner.nstep import steps_left  # noqa: E402

CHUNK_LEN, LIMIT = 32, 0.9


def chunked(n: int, generator: torch.Generator):
    """`n` random transitions as chunks of CHUNK_LEN consecutive steps (n a multiple of it)."""
    data = random_transitions(n, generator)
    data["steps_left"] = steps_left([CHUNK_LEN] * (n // CHUNK_LEN))
    return data


def make_core(n_step: int, fill: int) -> tuple[LearningCore, list]:
    scale = dataclasses.replace(SCALES["small"], n_step=n_step)
    core = LearningCore(AgentConfig(name="gvf_ddpg", metrics_every=10**9), scale, buffer_size=fill, warmup=1)
    g = torch.Generator().manual_seed(0)
    for _ in range(fill // 256):
        core.add(chunked(256, g))
    return core, [chunked(CHUNK_LEN, g) for _ in range(8)]


def rate(core: LearningCore, inserts: list, n: int) -> float:
    """Updates/s with one chunk inserted every CHUNK_LEN / (batch / samples_per_insert) updates,
    the learner service's rate limit."""
    every = max(1, CHUNK_LEN // (core.batch_size // SAMPLES_PER_INSERT))
    start = time.perf_counter()
    for i in range(n):
        if i % every == 0:
            core.add(inserts[(i // every) % len(inserts)])
        core.update()
    return n / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    parser.add_argument("--rounds", type=int, default=12)
    parser.add_argument("--per-round", type=int, default=10)
    parser.add_argument("--n", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    started = time.perf_counter()
    cores = {1: make_core(1, 4096), args.n: make_core(args.n, 4096)}
    for core, inserts in cores.values():  # warm-up: the discriminator's warm start, allocator, Adam state
        rate(core, inserts, 2)
    rates: dict[int, list[float]] = {n: [] for n in cores}
    for _ in range(args.rounds):
        for n, (core, inserts) in cores.items():
            rates[n].append(rate(core, inserts, args.per_round))
    one, many = statistics.median(rates[1]), statistics.median(rates[args.n])
    ratio = many / one
    print(
        json.dumps(
            {
                "n_step": args.n,
                "updates_per_s_1_step": round(one, 2),
                f"updates_per_s_{args.n}_step": round(many, 2),
                "ratio": round(ratio, 3),
                "limit_ratio": LIMIT,
                "meets_limit": ratio >= LIMIT,
                "scale": "small",
                "threads": args.threads,
                "rounds": args.rounds,
                "seconds": round(time.perf_counter() - started, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
