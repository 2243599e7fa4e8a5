"""Simulator throughput: LaneDrive-v0 with camera (1 env, and a batch of 16 in one process)
against gymnasium's CarRacing-v3 measured in the same run, all on one core.

Usage: python bench/sim.py [--seconds 5]. The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import gymnasium as gym
import numpy as np

import actors.envs  # noqa: F401  (registers LaneDrive-v0)
from actors.envs.tracks import track_names

TARGET_STEPS_PER_S, TARGET_RATIO = 3000.0, 20.0


def steps_per_s(env, seconds: float, batch: int = 1) -> float:
    """Env steps per second under uniformly random actions (drawn beforehand), resets included."""
    low, high = env.action_space.low, env.action_space.high
    actions = np.random.default_rng(0).uniform(low, high, (1000, *low.shape)).astype(np.float32)
    env.reset(seed=0)
    for k in range(20):  # warm caches
        env.step(actions[k])
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for k in range(n % 1000, n % 1000 + 20):
            _, _, term, trunc, _ = env.step(actions[k])
            if batch == 1 and (term or trunc):
                env.reset()
        n += 20
    return n * batch / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=5.0, help="measuring time per simulator")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core, as the target says

    lane = gym.make("LaneDrive-v0", track="all")
    start = time.perf_counter()
    for name in track_names("all"):  # draw every road map once, as a long-running actor would
        lane.reset(seed=0, options={"track": name})
    map_build_s = (time.perf_counter() - start) / len(track_names("all"))
    single = steps_per_s(lane, args.seconds)
    print(f"LaneDrive-v0 1 env: {single:,.0f} steps/s (first reset per road {map_build_s * 1e3:.0f} ms)")

    vec = gym.make_vec("LaneDrive-v0", num_envs=16, vectorization_mode="vector_entry_point", track="all")
    batch16 = steps_per_s(vec, args.seconds, batch=16)
    print(f"LaneDrive-v0 batch of 16: {batch16:,.0f} steps/s")

    car = gym.make("CarRacing-v3")
    carracing = steps_per_s(car, args.seconds)
    print(f"CarRacing-v3: {carracing:,.0f} steps/s")

    ratio = single / carracing
    print(
        json.dumps(
            {
                "lanedrive_steps_per_s": round(single, 1),
                "lanedrive_batch16_steps_per_s": round(batch16, 1),
                "carracing_steps_per_s": round(carracing, 1),
                "ratio_vs_carracing": round(ratio, 2),
                "map_build_ms_per_road": round(map_build_s * 1e3, 1),
                "target_steps_per_s": TARGET_STEPS_PER_S,
                "target_ratio": TARGET_RATIO,
                "meets_targets": bool(single >= TARGET_STEPS_PER_S and ratio >= TARGET_RATIO),
                "cores": 1,
                "numpy": np.__version__,
            }
        )
    )


if __name__ == "__main__":
    main()
