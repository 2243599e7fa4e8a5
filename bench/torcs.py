"""TORCS lockstep throughput (issue 15): control steps per second of one TORCS process driven by
TorcsProcess (0.1 s of simulated time a step, no camera), the same with a relaunch every 1,200 steps
(an episode), N processes stepped side by side from N Python processes; then TorcsDrive-v0 (the
gymnasium env: camera rendered every step, resets every 1,200 steps) for one process and for N
spawned Python processes each with its own TORCS; and LaneDrive-v0 (camera included) in the same run.

Usage: python bench/torcs.py [--seconds 3] [--procs 2]. Needs `make torcs`. The last line printed
is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import time

import gymnasium as gym
import numpy as np

import actors.envs  # noqa: F401  (registers LaneDrive-v0 and TorcsDrive-v0)
from actors.envs.torcs.protocol import TorcsProcess
from actors.envs.torcs.race import RaceSpec

EPISODE_STEPS = 1200  # LaneDrive's truncation: the reset cadence an actor sees
ROAD = RaceSpec("g-track-1", "road", start=0.0)


def _centre_steer(state) -> float:
    """Keeps the car on the road so the physics run the usual case, not a car stuck in a wall."""
    return float(np.clip(2.0 * state.angle - 0.15 * state.to_middle, -1.0, 1.0))


def torcs_steps_per_s(seconds: float, episode_steps: int | None) -> float:
    with TorcsProcess() as torcs:
        state = torcs.reset(ROAD)
        n, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            state = torcs.step(_centre_steer(state), 18.0)
            n += 1
            if episode_steps and n % episode_steps == 0:
                state = torcs.reset(ROAD)
        return n / (time.perf_counter() - start)


def torcs_drive_steps_per_s(seconds: float) -> float:
    """TorcsDrive-v0 with its camera, driven by the kinematic controller (the car stays on the road);
    an episode ends at 1,200 steps and the env is reset as an actor would."""
    from actors.controllers.kinematic import KinematicController

    env = gym.make("TorcsDrive-v0", track=ROAD.track, max_steps=EPISODE_STEPS).unwrapped
    try:
        controller = KinematicController(vehicle=env.vehicle)
        _, info = env.reset(seed=0)  # the first reset may draw the road's camera map: not timed
        n, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            _, _, terminated, truncated, info = env.step(controller.act(info))
            n += 1
            if terminated or truncated:
                _, info = env.reset()
        return n / (time.perf_counter() - start)
    finally:
        env.close()


def _worker(seconds: float, camera: bool, out: mp.Queue) -> None:
    out.put(torcs_drive_steps_per_s(seconds) if camera else torcs_steps_per_s(seconds, EPISODE_STEPS))


def parallel_steps_per_s(procs: int, seconds: float, camera: bool = False) -> float:
    """Sum over ``procs`` spawned Python processes, each stepping its own TORCS (with the env's camera if asked)."""
    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    workers = [ctx.Process(target=_worker, args=(seconds, camera, out)) for _ in range(procs)]
    for w in workers:
        w.start()
    try:
        return sum(out.get(timeout=seconds + 60) for _ in workers)
    finally:
        for w in workers:
            w.join(timeout=10)
            if w.is_alive():
                w.terminate()


def lane_drive_steps_per_s(seconds: float) -> tuple[float, float]:
    """Steps/s under random actions as bench/sim.py measures it (resets included: they end an episode
    every ~20 steps), and the same with the reset time left out."""
    env = gym.make("LaneDrive-v0", track="all")  # the named road library, as bench/sim.py
    actions = np.random.default_rng(0).uniform(-1, 1, (1000, 2)).astype(np.float32)
    env.reset(seed=0)
    n, in_reset, start = 0, 0.0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        _, _, term, trunc, _ = env.step(actions[n % 1000])
        n += 1
        if term or trunc:
            t = time.perf_counter()
            env.reset()
            in_reset += time.perf_counter() - t
    elapsed = time.perf_counter() - start
    env.close()
    return n / elapsed, n / (elapsed - in_reset)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--procs", type=int, default=2)
    args = parser.parse_args()
    result = {
        "torcs_steps_per_s": torcs_steps_per_s(args.seconds, None),
        "torcs_steps_per_s_with_resets": torcs_steps_per_s(args.seconds, EPISODE_STEPS),
        "torcs_procs": args.procs,
        "torcs_parallel_steps_per_s": parallel_steps_per_s(args.procs, args.seconds),
        "torcs_drive_steps_per_s": torcs_drive_steps_per_s(args.seconds),  # with the camera
        "torcs_drive_parallel_steps_per_s": parallel_steps_per_s(args.procs, args.seconds, camera=True),
    }
    result["torcs_drive_steps_per_s_per_process"] = result["torcs_drive_parallel_steps_per_s"] / args.procs
    result["lane_drive_steps_per_s"], result["lane_drive_steps_per_s_without_resets"] = lane_drive_steps_per_s(
        args.seconds
    )
    result["torcs_over_lane_drive_without_resets"] = (
        result["torcs_steps_per_s"] / result["lane_drive_steps_per_s_without_resets"]
    )
    print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in result.items()}))


if __name__ == "__main__":
    main()
