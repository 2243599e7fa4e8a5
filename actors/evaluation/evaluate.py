"""Drive a policy without exploration noise over a set of roads and compute the paper's
metrics per road (one lap from the start line, centred, or until the episode ends)."""

from __future__ import annotations

from typing import Callable

import numpy as np

from actors.envs.lane_drive import LaneDriveEnv
from actors.envs.tracks import track_names
from actors.evaluation.metrics import drive_metrics

# policy(obs, info) -> action (2,) in [-1, 1]
PolicyFn = Callable[[dict, dict], np.ndarray]


def drive(env: LaneDriveEnv, policy: PolicyFn, track: str, direction: str) -> dict:
    """One lap of `track`; returns metrics and the per-step trace (alpha, beta, speed, actions, progress)."""
    obs, info = env.reset(seed=0, options={"track": track, "direction": direction, "random_start": False})
    trace = {k: [] for k in ("reward", "speed", "alpha", "beta", "progress", "action")}
    done = False
    while not done and not info["lap_completed"]:
        action = np.asarray(policy(obs, info), np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        for key, value in (("reward", reward), ("speed", info["speed"]), ("alpha", info["alpha"]), ("beta", info["beta"]), ("progress", info["progress"]), ("action", action)):
            trace[key].append(value)
        done = terminated or truncated
    trace = {k: np.asarray(v, np.float32) for k, v in trace.items()}
    metrics = drive_metrics(trace["reward"], trace["speed"], trace["alpha"], trace["beta"], trace["action"], info["lap_completed"])
    return {"track": info["track"], "direction": direction, "metrics": metrics, "trace": trace}


def evaluate(policy: PolicyFn, split: str = "test", directions=("ccw", "cw"), tracks: list[str] | None = None, **env_kwargs) -> list[dict]:
    """Every road of `split` (or the named `tracks`) in each direction."""
    env = LaneDriveEnv(lighting=False, **env_kwargs)
    return [drive(env, policy, name, d) for name in (tracks or track_names(split)) for d in directions]


def summary(results: list[dict]) -> dict[str, float]:
    """Mean of every metric over the drives, plus the fraction of laps completed."""
    keys = results[0]["metrics"].keys()
    return {k: float(np.mean([r["metrics"][k] for r in results])) for k in keys}
