"""Drive a policy without exploration noise over a set of roads and compute the paper's
metrics per road (one lap from the start line, centred, or until the episode ends)."""

from __future__ import annotations

from typing import Callable

import numpy as np

from actors.envs.sim import LaneDriveSim
from actors.envs.tracks import track_names
from actors.evaluation.metrics import drive_metrics
from common.config.env import EnvConfig

# policy(obs, info) -> actions (n, 2) in [-1, 1], for a batch of n cars (info: name -> (n,) array)
PolicyFn = Callable[[dict, dict], np.ndarray]
TRACE = ("reward", "speed", "alpha", "beta", "progress", "action")


def evaluate(
    policy: PolicyFn, split: str = "test", directions=("ccw", "cw"), tracks: list[str] | None = None, **env_kwargs
) -> list[dict]:
    """One lap of every road of `split` (or the named `tracks`) in each direction; returns per drive
    its metrics and per-step trace (alpha, beta, speed, actions, progress).

    All drives run at once, one car each, so the policy sees one batch per step (a network's
    forward costs about as much for 12 cars as for 1); a car's drive ends at its lap or episode end.
    """
    drives = [(name, d) for name in (tracks or track_names(split)) for d in directions]
    sim = LaneDriveSim(EnvConfig.from_kwargs(lighting=False, **env_kwargs), len(drives))
    rng = np.random.default_rng(0)  # unused without random starts and lighting
    for i, (name, d) in enumerate(drives):
        sim.reset(i, rng, {"track": name, "direction": d, "random_start": False})
    infos = [sim.info(i) for i in range(len(drives))]
    traces = [{k: [] for k in TRACE} for _ in drives]
    running = np.array([not info["lap_completed"] for info in infos])
    while running.any():
        batch_info = {k: np.array([info[k] for info in infos]) for k in infos[0]}
        actions = np.asarray(policy(sim.observation(), batch_info), np.float32).reshape(len(drives), 2)
        terminated, truncated = sim.step(actions)  # finished cars drive on, unrecorded
        for i in np.flatnonzero(running):
            infos[i] = info = sim.info(i)
            for key, value in zip(
                TRACE, (sim.reward[i], info["speed"], info["alpha"], info["beta"], info["progress"], actions[i])
            ):
                traces[i][key].append(value)
            running[i] = not (terminated[i] or truncated[i] or info["lap_completed"])
    results = []
    for (_, d), info, trace in zip(drives, infos, traces):
        trace = {k: np.asarray(v, np.float32) for k, v in trace.items()}
        metrics = drive_metrics(
            trace["reward"], trace["speed"], trace["alpha"], trace["beta"], trace["action"], info["lap_completed"]
        )
        results.append({"track": info["track"], "direction": d, "metrics": metrics, "trace": trace})
    return results


def summary(results: list[dict]) -> dict[str, float]:
    """Mean of every metric over the drives, plus the fraction of laps completed."""
    keys = results[0]["metrics"].keys()
    return {k: float(np.mean([r["metrics"][k] for r in results])) for k in keys}
