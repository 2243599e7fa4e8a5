"""TORCS soak (issue 15): TorcsDrive-v0 stepped continuously for --minutes by the kinematic controller
on the train roads (a new road at every reset), across resets and TORCS relaunches. Counts episodes
begun and ended (an episode begun and never ended by termination or truncation is lost), relaunches
and errors, and samples this Python process's resident memory (is it flat?).

Usage: python bench/torcs_soak.py [--minutes 60] [--sample-every 30] [--kill-every S]. --kill-every
SIGKILLs the running TORCS every S seconds, mid-episode, so that relaunches after a death are soaked
too (the episode it ends counts as truncated, ``info["relaunched"]``). Needs `make torcs`. The last
line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import time

import gymnasium as gym

import actors.envs  # noqa: F401  (registers TorcsDrive-v0)
from actors.evaluation.policies import kinematic_policy


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--sample-every", type=float, default=30.0, help="seconds between memory samples")
    parser.add_argument("--kill-every", type=float, default=0.0, help="SIGKILL TORCS this often (s); 0: never")
    args = parser.parse_args()
    env = gym.make("TorcsDrive-v0", track="train")
    policy = kinematic_policy(env.unwrapped.vehicle)
    procs = env.unwrapped.sim.procs
    counts = {"steps": 0, "begun": 0, "terminated": 0, "truncated": 0, "errors": 0, "laps": 0}
    counts |= {"kills": 0, "ended_by_relaunch": 0}
    samples: list[tuple[float, float]] = []
    start = next_sample = time.monotonic()
    end = start + args.minutes * 60
    next_kill = start + args.kill_every if args.kill_every > 0 else float("inf")
    obs, info = env.reset(seed=0)
    counts["begun"] += 1
    while time.monotonic() < end:
        if time.monotonic() >= next_kill:
            for p in procs:
                if p.alive:  # TORCS runs in its own session: kill the whole group, as a crash would
                    os.killpg(p.proc.pid, signal.SIGKILL)
                    counts["kills"] += 1
            next_kill += args.kill_every
        try:
            obs, _, terminated, truncated, info = env.step(policy(obs, info))
        except Exception as e:  # counted, and the run goes on from a reset: the soak measures, not hides
            counts["errors"] += 1
            print(f"step failed: {e!r}", flush=True)
            obs, info = env.reset()
            counts["begun"] += 1
            continue
        counts["steps"] += 1
        if terminated or truncated:
            counts["terminated" if terminated else "truncated"] += 1
            counts["laps"] += int(bool(info.get("lap_completed")))
            counts["ended_by_relaunch"] += int(bool(info.get("relaunched")))
            obs, info = env.reset()
            counts["begun"] += 1
        if time.monotonic() >= next_sample:
            samples.append((round(time.monotonic() - start, 1), round(rss_mb(), 1)))
            next_sample += args.sample_every
    samples.append((round(time.monotonic() - start, 1), round(rss_mb(), 1)))
    env.close()
    ended = counts["terminated"] + counts["truncated"]
    half = [mb for t, mb in samples if t >= samples[-1][0] / 2]
    result = {
        "minutes": args.minutes,
        **counts,
        "ended": ended,
        # the episode running at the stop is the only one allowed to be open
        "lost_episodes": counts["begun"] - ended - 1,
        "steps_per_s": counts["steps"] / (samples[-1][0] or 1.0),
        "launches": sum(p.launches for p in procs),
        "relaunches": sum(p.relaunches for p in procs),
        "rss_mb": {
            "first": samples[0][1],
            "last": samples[-1][1],
            "max": max(mb for _, mb in samples),
            "second_half_growth": round(half[-1] - half[0], 1),
        },
        "samples": samples,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
