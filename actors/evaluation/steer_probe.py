"""Does steering towards the lane's centre pay under the policy itself, where its critic says so?

A checkpoint's policy drives the test laps without noise. Every `every` steps, at each car off the
centre (|alpha| >= OFF_CENTRE) and still on its lap, the simulator is branched twice
(`LaneDriveSim.branch`): one step with the policy's steering moved `eps` towards the centre, one
with it moved `eps` away; then the policy drives both branches on for `horizon` steps. Half the
difference of the two discounted returns over `eps` (DDPG's reward of the checkpoint: crash
penalty, offset weight) is the true slope of Q^pi along the steering, by central differences on
a deterministic simulator (the nudge clipped at the steering's bounds, the difference is over the
steering actually moved); the critic's dQ/d(steering) at the same state and action is the slope
the actor climbs (where its output is not held at a bound by the clip). Both are signed so that
positive is "towards the centre". With TD3's twin critics each twin's slope is read, and their mean:
the slope an actor that climbed the twins' mean would follow (do the twins' errors cancel?).

If the true slope points to the centre where the critic's does not, the critic keeps the offset;
if the true slope itself does not, one step towards the centre does not pay under this policy (it
drives back to its offset), and no local step of DDPG's actor can find the centre.

    python -m actors.evaluation.steer_probe runs/offset-3-ym --last 1 --out docs/results/steer-probe.md
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from actors.envs.sim import LaneDriveSim
from actors.evaluation.critic_probe import load_probed, twin_critics
from actors.evaluation.main import eval_env_kwargs
from actors.evaluation.road_gap import cell, checkpoint_tool, roads
from common.config.agent import ScaleConfig, shaped_reward, step_sizes
from common.config.env import NOISE_FREE, OFF_CENTRE, EnvConfig
from common.config.run import RunConfig
from common.networks import phi

# act(sim) -> (features for the critic, actions (n, 2) in [-1, 1]);
# slope(features, actions) -> dQ/dsteer, (n,) or (n, k) for k critics
ActFn = Callable[[LaneDriveSim], tuple[object, np.ndarray]]
SlopeFn = Callable[[object, np.ndarray], np.ndarray]


def branch_returns(sim: LaneDriveSim, act: ActFn, first: np.ndarray, reward: Callable, horizon: int, discount: float):
    """Discounted return of each car over `horizon` steps of a branch of `sim` that starts with
    the actions `first` and then follows `act`; a car's return stops where it leaves the lane."""
    b = sim.branch()
    g, alive, weight, actions = np.zeros(sim.n), np.ones(sim.n, bool), 1.0, first
    for _ in range(horizon):
        terminated, _ = b.step(actions)  # the learner bootstraps through the time limit: Q^pi has none
        g += alive * weight * reward(b, terminated)
        alive &= ~terminated
        weight *= discount
        if not alive.any():
            break
        actions = act(b)[1]
    return g


def step_laps(sim: LaneDriveSim, actions: np.ndarray) -> np.ndarray:
    """Step every car of `sim` with `actions`; the cars whose test lap ended there (left the lane,
    ran out of time or completed it)."""
    terminated, truncated = sim.step(actions)
    lapped = np.array([sim.info(i)["lap_completed"] for i in range(sim.n)], bool)
    return terminated | truncated | lapped


def probe_drives(
    sim: LaneDriveSim,
    act: ActFn,
    slope: SlopeFn,
    reward: Callable,
    discount: float,
    every: int = 40,
    horizon: int = 300,
    eps: float = 0.1,
    min_offset: float = OFF_CENTRE,
) -> np.ndarray:
    """Drive every car of `sim` (already reset) to its lap's or episode's end; rows (alpha, true
    slope, each critic's slope) at the probed off-centre states, slopes signed towards the centre."""
    running, rows, step = np.ones(sim.n, bool), [], 0
    while running.any():
        features, actions = act(sim)
        off = running & (np.abs(sim.alpha) >= min_offset)
        if step % every == 0 and off.any():
            towards = -np.sign(sim.alpha)  # steering left (+) moves alpha up
            shifted = [actions.copy(), actions.copy()]
            for sign, a in zip((1.0, -1.0), shifted):
                a[:, 0] = np.clip(a[:, 0] + sign * eps * towards * off, -1.0, 1.0)
            g_to, g_away = (branch_returns(sim, act, a, reward, horizon, discount) for a in shifted)
            critic = towards[:, None] * np.asarray(slope(features, actions)).reshape(sim.n, -1)
            moved = towards * (shifted[0][:, 0] - shifted[1][:, 0])  # less than 2 eps where clipped at a bound
            for i in np.flatnonzero(off & (moved > 0)):
                rows.append((sim.alpha[i], (g_to[i] - g_away[i]) / moved[i], *critic[i]))
        running &= ~step_laps(sim, actions)
        step += 1
    return np.asarray(rows, np.float64).reshape(-1, len(rows[0]) if rows else 3)


def summarise(rows: np.ndarray) -> dict:
    """Shares of the probed states where each slope points to the centre, and where they agree;
    with twin critics (a fourth column) also the second twin's and the twins' mean slope."""
    if not len(rows):
        return {"states": 0}
    true, critic = rows[:, 1], rows[:, 2]
    pays = true > 0
    twins = {}
    if rows.shape[1] > 3:
        mean = rows[:, 2:].mean(1)
        twins = {
            "twin2_to_centre": float((rows[:, 3] > 0).mean()),
            "twin2_where_it_pays": float((rows[pays, 3] > 0).mean()) if pays.any() else None,
            "twins_agree": float(((rows[:, 2] > 0) == (rows[:, 3] > 0)).mean()),
            "mean_to_centre": float((mean > 0).mean()),
            "mean_where_it_pays": float((mean[pays] > 0).mean()) if pays.any() else None,
        }
    return {
        "states": len(rows),
        "mean_abs_alpha": float(np.abs(rows[:, 0]).mean()),
        "true_to_centre": float(pays.mean()),
        "critic_to_centre": float((critic > 0).mean()),
        "agree": float(((critic > 0) == pays).mean()),
        "critic_where_it_pays": float((critic[pays] > 0).mean()) if pays.any() else None,
        "true_slope_median": float(np.median(true)),
        "critic_slope_median": float(np.median(critic)),
        **twins,
    }


def network_act(policy: torch.nn.Module) -> ActFn:
    """The predictive policy's phi(s) and action at every car of a sim."""

    @torch.no_grad()
    def act(sim: LaneDriveSim):
        obs = sim.observation()
        image, speed, last = (torch.from_numpy(np.asarray(obs[k])) for k in ("image", "speed", "last_action"))
        x = phi(policy.gvf(image, speed, last), speed, last)
        return x, policy.actor(x).clamp(-1.0, 1.0).numpy()

    return act


def critic_slope(*critics: torch.nn.Module) -> SlopeFn:
    """dQ/d(steering) of each critic at (phi, action), (n, k)."""

    def slope(x: torch.Tensor, actions: np.ndarray) -> np.ndarray:
        columns = []
        for critic in critics:
            a = torch.from_numpy(actions).requires_grad_(True)
            (grad,) = torch.autograd.grad(critic(x, a).sum(), a)
            columns.append(grad[:, 0].numpy())
        return np.stack(columns, 1)

    return slope


def ddpg_reward(scale: ScaleConfig, v_max: float):
    """DDPG's reward of a branch's last step, as the learner formed it (`shaped_reward`)."""
    return lambda sim, terminated: shaped_reward(
        sim.reward, terminated.astype(float), sim.v / v_max * np.abs(sim.alpha), scale
    )


def sim_on_test_laps(cfg: RunConfig) -> LaneDriveSim:
    """One car per test road and direction, at each lap's start, as the run's evaluator drives them."""
    env = EnvConfig.from_kwargs(**{**eval_env_kwargs(cfg), **NOISE_FREE})
    drives = [(name, d) for name in roads(cfg)["test"] for d in cfg.eval.directions]
    sim = LaneDriveSim(env, len(drives))
    rng = np.random.default_rng(0)
    for i, (name, d) in enumerate(drives):
        sim.reset(i, rng, {"track": name, "direction": d, "random_start": False})
    return sim


def measure_checkpoint(path: Path, cfg: RunConfig | None = None, **probe_kwargs) -> dict:
    state, agent, scale, policy, _ = load_probed(path)
    critics = twin_critics(state, agent, scale)  # the first is the one TD3's actor climbs
    cfg = cfg or RunConfig()
    sim = sim_on_test_laps(cfg)
    discount = step_sizes(agent, scale)["discount"]
    reward = ddpg_reward(scale, sim.cfg.vehicle.v_max)
    rows = probe_drives(sim, network_act(policy), critic_slope(*critics), reward, discount, **probe_kwargs)
    settings = {"every": 40, "horizon": 300, "eps": 0.1, **probe_kwargs}
    return {"agent": agent.name, "updates": state["core"]["updates"], "probe": settings, **summarise(rows)}


def report(measured: dict[str, dict]) -> list[str]:
    settings = sorted({json.dumps(m.get("probe"), sort_keys=True) for m in measured.values()})
    lines = [
        f"Off-centre test-lap states (|alpha| >= {OFF_CENTRE}); slopes of Q along the steering, positive "
        "towards the centre: true (Q^pi by central differences of the steering nudged eps each way, the "
        f"policy driving `horizon` steps on) and the critic's. Probe settings: {', '.join(settings)}.",
        "",
        "| checkpoint | updates | states | mean abs(alpha) | true slope to the centre | critic's to the centre "
        "| agree | critic's where it pays | median true slope | median critic's | second twin's to the centre "
        "| second twin's where it pays | twins agree | twins' mean to the centre | twins' mean where it pays |",
        "|" + " --- |" * 15,
    ]
    for path, m in measured.items():
        lines.append(
            f"| {path} | {m['updates']} | {m['states']} | {cell(m, 'mean_abs_alpha', '.2f')} "
            f"| {cell(m, 'true_to_centre', '.2f')} | {cell(m, 'critic_to_centre', '.2f')} | {cell(m, 'agree', '.2f')} "
            f"| {cell(m, 'critic_where_it_pays', '.2f')} | {cell(m, 'true_slope_median', '+.2f')} "
            f"| {cell(m, 'critic_slope_median', '+.2f')} | {cell(m, 'twin2_to_centre', '.2f')} "
            f"| {cell(m, 'twin2_where_it_pays', '.2f')} | {cell(m, 'twins_agree', '.2f')} "
            f"| {cell(m, 'mean_to_centre', '.2f')} | {cell(m, 'mean_where_it_pays', '.2f')} |"
        )
    return lines


def main(argv: list[str] | None = None) -> None:
    checkpoint_tool(
        argv,
        __doc__,
        "actors.evaluation.steer_probe",
        measure_checkpoint,
        report,
        "Does steering to the centre pay, and does the critic say so?",
    )


if __name__ == "__main__":
    main()
