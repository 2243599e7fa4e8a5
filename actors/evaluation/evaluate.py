"""Drive a policy without exploration noise over a set of roads and compute the paper's
metrics per road (one lap from the start line, centred, or until the episode ends).

On TORCS (``id='TorcsDrive-v0'``) each road is driven once, its own way (TORCS roads have one
direction), one TORCS process per road, all stepped together as LaneDrive's cars are.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from actors.envs.sim import LaneDriveSim
from actors.envs.simulators import is_torcs, road_names
from actors.evaluation.metrics import CONTROL_HZ, drive_metrics
from common.config.env import NOISE_FREE, EnvConfig

# policy(obs, info) -> actions (n, 2) in [-1, 1], for a batch of n cars (info: name -> (n,) array)
PolicyFn = Callable[[dict, dict], np.ndarray]
TRACE = ("reward", "speed", "alpha", "beta", "progress", "action")
TORCS_DIRECTION = "forward"  # the one way a TORCS road is driven
LAP_MARGIN = 1.5  # a TORCS lap may take this many times as long as at the slowest target speed


def evaluate(
    policy: PolicyFn, split: str = "test", directions=("ccw", "cw"), tracks: list[str] | None = None, **env_kwargs
) -> list[dict]:
    """One lap of every road of `split` (or the named `tracks`) in each direction; returns per drive
    its metrics and per-step trace (alpha, beta, speed, actions, progress).

    All drives run at once, one car each, so the policy sees one batch per step (a network's
    forward costs about as much for 12 cars as for 1); a car's drive ends at its lap or episode end.
    """
    cfg = EnvConfig.from_kwargs(**{**env_kwargs, **NOISE_FREE})
    names = list(tracks or road_names(cfg, split))
    if is_torcs(cfg):
        drives = [(name, TORCS_DIRECTION) for name in names]
        sim, horizons = _torcs_sim(cfg, names)
        try:
            options = [{"track": n, "random_start": False} for n in names]
            return _drive(policy, sim, drives, options, torcs=True, horizons=horizons)
        finally:
            sim.close()
    drives = [(name, d) for name in names for d in directions]
    sim = LaneDriveSim(cfg, len(drives))
    options = [{"track": name, "direction": d, "random_start": False} for name, d in drives]
    return _drive(policy, sim, drives, options, torcs=False)


def _torcs_sim(cfg: EnvConfig, names: list[str]):
    """One TORCS process per road, and per road a horizon that fits its lap (spring is 22 km: 2,200 s at 10 m/s)."""
    from actors.envs.torcs.env import make_sim
    from actors.envs.torcs.sim import road_geometry

    sim = make_sim(cfg, len(names))
    lengths = np.array([road_geometry(n, sim.data_dir)[0].length for n in names])
    slowest = 0.5 * cfg.vehicle.v_max * 0.1  # m per 0.1 s step at the slowest target speed
    horizons = np.maximum(cfg.max_steps, np.ceil(LAP_MARGIN * lengths / slowest))
    sim.cfg = dataclasses.replace(cfg, max_steps=int(horizons.max()))  # each drive ends at its own horizon
    return sim, horizons


def _drive(
    policy: PolicyFn, sim, drives: list[tuple[str, str]], options: list[dict], torcs: bool, horizons=None
) -> list[dict]:
    rng = np.random.default_rng(0)  # unused without random starts and lighting
    for i, opts in enumerate(options):
        sim.reset(i, rng, opts)
    infos = [sim.info(i) for i in range(len(drives))]
    traces = [{k: [] for k in TRACE} for _ in drives]
    running = np.array([not info["lap_completed"] for info in infos])
    while running.any():
        batch_info = {k: np.array([info[k] for info in infos]) for k in infos[0]}
        actions = np.asarray(policy(sim.observation(), batch_info), np.float32).reshape(len(drives), 2)
        # finished LaneDrive cars drive on, unrecorded; a finished TORCS car's process waits, costing nothing
        terminated, truncated = sim.step(actions, running) if torcs else sim.step(actions)
        for i in np.flatnonzero(running):
            infos[i] = info = sim.info(i)
            for key, value in zip(
                TRACE, (sim.reward[i], info["speed"], info["alpha"], info["beta"], info["progress"], actions[i])
            ):
                traces[i][key].append(value)
            over = horizons is not None and len(traces[i]["reward"]) >= horizons[i]
            running[i] = not (terminated[i] or truncated[i] or info["lap_completed"] or over)
    hz = CONTROL_HZ if torcs else 1.0 / sim.cfg.vehicle.dt  # TORCS steps 0.1 s whatever its config says
    results = []
    for (_, d), info, trace in zip(drives, infos, traces):
        trace = {k: np.asarray(v, np.float32) for k, v in trace.items()}
        metrics = drive_metrics(
            trace["reward"], trace["speed"], trace["alpha"], trace["beta"], trace["action"], info["lap_completed"], hz
        )
        results.append({"track": info["track"], "direction": d, "metrics": metrics, "trace": trace})
    return results


def summary(results: list[dict]) -> dict[str, float]:
    """Mean of every metric over the drives, plus the fraction of laps completed."""
    keys = results[0]["metrics"].keys()
    return {k: float(np.mean([r["metrics"][k] for r in results])) for k in keys}
