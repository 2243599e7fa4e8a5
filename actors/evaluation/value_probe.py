"""How far is GVF-DDPG's critic from the value of its own policy?

A checkpoint's policy drives the test laps without noise. Every `every` steps, at each car still
on its lap, the critic's Q(phi, pi(phi)) is read, and the simulator is branched
(`LaneDriveSim.branch`) to let the policy drive on for `horizon` steps: the discounted return of
DDPG's reward as the learner formed it (crash penalty, offset weight) is Q^pi at that state, exact
on the deterministic simulator up to the horizon's tail (discount**horizon of the rest). Their
difference is the critic's bias where the policy drives; their correlation over the states says
whether the critic at least ranks them (the actor climbs Q's shape, not its level).

    python -m actors.evaluation.value_probe runs/ym-actor-delay-4 --last 1 --out docs/results/value-probe.md
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from actors.envs.sim import LaneDriveSim
from actors.evaluation.critic_probe import load_probed
from actors.evaluation.road_gap import cell, checkpoint_tool
from actors.evaluation.steer_probe import ActFn, branch_returns, ddpg_reward, network_act, sim_on_test_laps, step_laps
from common.config.agent import step_sizes
from common.config.run import RunConfig


def value_rows(sim: LaneDriveSim, act: ActFn, critic, reward, discount: float, every: int = 50, horizon: int = 500):
    """Drive every car of `sim` (already reset) to its lap's or episode's end. Returns rows
    (alpha, speed, critic's Q(phi, pi(phi)), the policy's discounted return) at the probed states."""
    running, rows, step = np.ones(sim.n, bool), [], 0
    while running.any():
        features, actions = act(sim)
        if step % every == 0:
            with torch.no_grad():
                q = critic(features, torch.from_numpy(actions)).reshape(-1).numpy()
            g = branch_returns(sim, act, actions, reward, horizon, discount)
            rows.extend((sim.alpha[i], sim.v[i], q[i], g[i]) for i in np.flatnonzero(running))
        running &= ~step_laps(sim, actions)
        step += 1
    return np.asarray(rows, np.float64).reshape(-1, 4)


def summarise(rows: np.ndarray) -> dict:
    """The critic's level against the returns, and how well it ranks the states."""
    if not len(rows):
        return {"states": 0}
    q, g = rows[:, 2], rows[:, 3]
    ranked = len(rows) > 2 and q.std() > 0 and g.std() > 0
    return {
        "states": len(rows),
        "q_median": float(np.median(q)),
        "return_median": float(np.median(g)),
        "bias_median": float(np.median(q - g)),
        "below_share": float((q < g).mean()),
        "corr": float(np.corrcoef(q, g)[0, 1]) if ranked else None,
    }


def measure_checkpoint(path: Path, cfg: RunConfig | None = None, every: int = 100, horizon: int = 500) -> dict:
    state, agent, scale, policy, critic = load_probed(path)
    sim = sim_on_test_laps(cfg or RunConfig())
    reward = ddpg_reward(scale, sim.cfg.vehicle.v_max)
    rows = value_rows(sim, network_act(policy), critic, reward, step_sizes(agent, scale)["discount"], every, horizon)
    return {"agent": agent.name, "updates": state["core"]["updates"], **summarise(rows)}


def report(measured: dict[str, dict]) -> list[str]:
    lines = [
        "Test-lap states every 100th step, the policy driving without noise: the critic's Q(phi, pi(phi)) "
        "against the policy's discounted return of DDPG's reward over the next 500 steps (the branched "
        "simulator), and their correlation over the states.",
        "",
        "| checkpoint | updates | states | median Q | median return | median Q - return | Q below the return "
        "| corr(Q, return) |",
        "|" + " --- |" * 8,
    ]
    for path, m in measured.items():
        lines.append(
            f"| {path} | {m['updates']} | {m['states']} | {cell(m, 'q_median', '.1f')} "
            f"| {cell(m, 'return_median', '.1f')} | {cell(m, 'bias_median', '+.1f')} "
            f"| {cell(m, 'below_share', '.2f')} | {cell(m, 'corr', '.2f')} |"
        )
    return lines


def main(argv: list[str] | None = None) -> None:
    checkpoint_tool(
        argv,
        __doc__,
        "actors.evaluation.value_probe",
        measure_checkpoint,
        report,
        "The critic against its policy's value",
    )


if __name__ == "__main__":
    main()
