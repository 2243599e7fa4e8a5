"""Ground truth for the GVFs on LaneDrive (the learner's tests and bench/rho_refresh.py): the
kinematic controller with OU noise as the behaviour, and Monte Carlo returns under the GVFs'
target policy tau from the states it visits."""

from __future__ import annotations

import copy

import numpy as np
import torch
from tensordict import TensorDict

from actors.controllers.kinematic import KinematicController
from actors.envs.lane_drive import LaneDriveEnv, LaneDriveVectorEnv
from actors.exploration import OrnsteinUhlenbeck


def _column(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, np.float32).reshape(-1, 1)


def collect(n_envs: int, n_steps: int, seed: int, sigma: float = 0.1) -> TensorDict:
    """Transitions (n_envs * n_steps,) in the learner's input convention, car-major."""
    env, controller = LaneDriveVectorEnv(n_envs), KinematicController()
    noise = OrnsteinUhlenbeck(n_envs, 2, sigma=sigma, seed=seed)
    obs, info = env.reset(seed=seed)
    steps = []
    for _ in range(n_steps):
        action = np.clip(controller.act(info) + noise.sample(), -1, 1).astype(np.float32)
        next_obs, reward, terminated, truncated, next_info = env.step(action)
        done = terminated | truncated
        # a finished car is reset in the same step: its true next state is in final_*
        final = {k: v.copy() for k, v in next_obs.items()}
        final_alpha, final_beta = next_info["alpha"].copy(), next_info["beta"].copy()
        for i in np.flatnonzero(done):
            for key in final:
                final[key][i] = next_info["final_obs"][i][key]
            final_alpha[i] = next_info["final_info"]["alpha"][i]
            final_beta[i] = next_info["final_info"]["beta"][i]
        steps.append(
            {
                **obs,
                "alpha": _column(info["alpha"]),
                "beta": _column(info["beta"]),
                "action": action,
                "next": {
                    **final,
                    "alpha": _column(final_alpha),
                    "beta": _column(final_beta),
                    "reward": _column(reward),
                    "terminated": terminated.reshape(-1, 1),
                    "truncated": truncated.reshape(-1, 1),
                },
            }
        )
        noise.reset(done)
        obs, info = next_obs, next_info
    td = TensorDict(_stack(steps), batch_size=[n_steps, n_envs])
    return td.transpose(0, 1).contiguous().reshape(-1)


def _stack(steps: list[dict]) -> dict:
    return {
        k: _stack([s[k] for s in steps]) if isinstance(v, dict) else torch.as_tensor(np.stack([s[k] for s in steps]))
        for k, v in steps[0].items()
    }


def tau_returns(
    n_states: int,
    gammas: list[float],
    seed: int,
    sigma: float = 0.1,
    width: float = 0.1,
    horizon: int = 150,
    every: int = 10,
    terminal: str = "zero",
    track: str = "train",
) -> tuple[TensorDict, torch.Tensor]:
    """Observations of states visited by the behaviour, and one rollout's return under tau.

    From every `every`-th state the simulator is copied and driven by tau (actions drawn
    from the truncated normal of width `width` around the last action) until termination
    or `horizon` steps; returns (n_states, 2 * G) in the GVFs' order [alpha@gammas,
    beta@gammas], cumulants scaled by (1 - gamma). After a termination the return adds nothing
    ("zero") or the last cumulant forever ("absorbing"; learner.gvf's terminal conventions).
    """
    rng = np.random.default_rng(seed)
    env, controller = LaneDriveEnv(track=track), KinematicController()
    noise = OrnsteinUhlenbeck(1, 2, sigma=sigma, seed=seed)
    observations, returns = [], []
    obs, info = env.reset(seed=seed)
    step = 0
    while len(observations) < n_states:
        action = np.clip(controller.act(info) + noise.sample()[0], -1, 1).astype(np.float32)
        obs, _, terminated, truncated, info = env.step(action)
        step += 1
        if terminated or truncated:
            obs, info = env.reset()
            noise.reset()
            continue
        if step % every:
            continue
        sim, last, signals, ended = copy.deepcopy(env), obs["last_action"], [], False
        for _ in range(horizon):
            while True:  # exact truncated-normal sample around the last action
                a = last + width * rng.standard_normal(2)
                if np.all(np.abs(a) <= 1.0):
                    break
            tau_obs, _, tau_terminated, _, tau_info = sim.step(a.astype(np.float32))
            last = tau_obs["last_action"]
            signals.append((tau_info["alpha"], tau_info["beta"]))
            if tau_terminated:
                ended = True
                break
        signals, n = np.asarray(signals), len(signals)
        tail = (lambda g, c: g**n * signals[-1, c]) if ended and terminal == "absorbing" else (lambda g, c: 0.0)
        row = [sum((1 - g) * g**k * signals[k, c] for k in range(n)) + tail(g, c) for c in range(2) for g in gammas]
        observations.append({k: torch.as_tensor(v) for k, v in obs.items()})
        returns.append(row)
    obs_td = TensorDict({k: torch.stack([o[k] for o in observations]) for k in observations[0]}, batch_size=[n_states])
    return obs_td, torch.tensor(returns, dtype=torch.float32)
