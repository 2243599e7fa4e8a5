"""Where does GVF-DDPG's critic put the steering's credit: on the action, or on phi's last action?

The paper's phi(s) ends with the last action, and its OU noise (theta 1, dt 0.01) moves the action
by ~0.01 a step, so in the replay the action is nearly the last action plus the policy's own change:
a critic can credit the value of the steering to either input. On LaneDrive the last steering moves
the car only where the steering-rate limit binds (a change over 0.3 in one step), so credit on it is
credit the actor, which sets the action, cannot climb. A checkpoint's policy drives the test laps
without noise; every `every` steps, at each car off the centre (|alpha| >= OFF_CENTRE), the critic's
dQ/d(steering) and dQ/d(last steering) (phi's entry, the predictions held) are read, signed so that
positive is towards the centre; the policy's own change of steering per step is measured throughout.

    python -m actors.evaluation.credit_probe runs/ym-actor-delay-4 --last 1 --out docs/results/credit-probe.md
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from actors.envs.sim import LaneDriveSim
from actors.evaluation.critic_probe import load_probed
from actors.evaluation.road_gap import cell, checkpoint_tool
from actors.evaluation.steer_probe import ActFn, network_act, sim_on_test_laps, step_laps
from common.config.env import OFF_CENTRE
from common.config.run import RunConfig

LAST_STEER = -2  # phi = [predictions, speed, last steering, last target speed]


def credit_rows(sim: LaneDriveSim, act: ActFn, critic, every: int = 10, min_offset: float = OFF_CENTRE):
    """Drive every car of `sim` (already reset) to its lap's or episode's end. Returns rows (alpha,
    dQ/d(steering), dQ/d(last steering)) at the probed off-centre states, both towards the centre,
    and the policy's |change of steering| at every step of every running car."""
    running, rows, changes, step, previous = np.ones(sim.n, bool), [], [], 0, None
    while running.any():
        features, actions = act(sim)
        if previous is not None:
            changes.append(np.abs(actions[running, 0] - previous[running, 0]))
        previous = actions.copy()
        off = running & (np.abs(sim.alpha) >= min_offset)
        if step % every == 0 and off.any():
            x = features.clone().requires_grad_(True)
            a = torch.from_numpy(actions).requires_grad_(True)
            dx, da = torch.autograd.grad(critic(x, a).sum(), (x, a))
            towards = -np.sign(sim.alpha)  # steering left (+) moves alpha up
            for i in np.flatnonzero(off):
                rows.append((sim.alpha[i], towards[i] * da[i, 0].item(), towards[i] * dx[i, LAST_STEER].item()))
        running &= ~step_laps(sim, actions)
        step += 1
    return np.asarray(rows, np.float64).reshape(-1, 3), np.concatenate(changes) if changes else np.zeros(0)


def summarise(rows: np.ndarray, changes: np.ndarray) -> dict:
    """Shares of the probed states where each slope points to the centre, and their sizes."""
    steps = {"steering_change_median": float(np.median(changes)) if len(changes) else None}
    if not len(rows):
        return {"states": 0, **steps}
    action, last = rows[:, 1], rows[:, 2]
    return {
        "states": len(rows),
        "mean_abs_alpha": float(np.abs(rows[:, 0]).mean()),
        "action_to_centre": float((action > 0).mean()),
        "last_to_centre": float((last > 0).mean()),
        "action_slope_abs_median": float(np.median(np.abs(action))),
        "last_slope_abs_median": float(np.median(np.abs(last))),
        **steps,
    }


def measure_checkpoint(path: Path, cfg: RunConfig | None = None, every: int = 10) -> dict:
    state, agent, scale, policy, critic = load_probed(path)
    rows, changes = credit_rows(sim_on_test_laps(cfg or RunConfig()), network_act(policy), critic, every)
    return {"agent": agent.name, "updates": state["core"]["updates"], **summarise(rows, changes)}


def report(measured: dict[str, dict]) -> list[str]:
    lines = [
        f"Off-centre test-lap states (|alpha| >= {OFF_CENTRE}), every 10th step: the critic's slopes along "
        "the steering and along phi's last steering, positive towards the centre; the policy's change "
        "of steering per step over the whole drives.",
        "",
        "| checkpoint | updates | states | mean abs(alpha) | dQ/d(steering) to the centre | dQ/d(last steering) "
        "to the centre | median abs dQ/d(steering) | median abs dQ/d(last steering) | median change of steering a step |",
        "|" + " --- |" * 9,
    ]
    for path, m in measured.items():
        lines.append(
            f"| {path} | {m['updates']} | {m['states']} | {cell(m, 'mean_abs_alpha', '.2f')} "
            f"| {cell(m, 'action_to_centre', '.2f')} | {cell(m, 'last_to_centre', '.2f')} "
            f"| {cell(m, 'action_slope_abs_median', '.2f')} | {cell(m, 'last_slope_abs_median', '.2f')} "
            f"| {cell(m, 'steering_change_median', '.4f')} |"
        )
    return lines


def main(argv: list[str] | None = None) -> None:
    checkpoint_tool(
        argv,
        __doc__,
        "actors.evaluation.credit_probe",
        measure_checkpoint,
        report,
        "Where the critic puts the steering's credit",
    )


if __name__ == "__main__":
    main()
