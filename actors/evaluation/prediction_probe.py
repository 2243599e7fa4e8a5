"""Do the GVFs know which way the steering moves the car?

The GVFs predict alpha under tau, "repeat the last action" (paper section 3), so the slope of a
prediction along its input's last steering is a learned model of the steering's effect: the
discounted future offset if the car held a little more steering from now on. The critic's slope
along the steering pointed to the centre at chance (`steer_probe`); this probe asks whether the
predictions' slope has the sign the simulator gives.

A checkpoint's policy drives the test laps without noise. Every `every` steps, at each car still on
its lap (learner.offset_steer acts at every state, centred or not), the simulator is branched twice
(`LaneDriveSim.branch`) with the last action's steering nudged `eps` each way; each branch then
repeats that action (tau's mean) for `horizon` steps. Per gamma, the (1 - gamma)-scaled discounted sum of alpha (0 after the car
leaves the lane, the `zero` terminal convention) differenced over the steering moved is the true
slope; the GVF's is d v_alpha / d(last steering) by autograd at the unnudged input.

    python -m actors.evaluation.prediction_probe runs/x --last 1 --out docs/results/prediction-probe.md
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from actors.envs.sim import LaneDriveSim
from actors.evaluation.critic_probe import load_probed
from actors.evaluation.road_gap import checkpoint_tool
from actors.evaluation.steer_probe import ActFn, network_act, sim_on_test_laps, step_laps
from common.config.run import RunConfig
from common.networks import prediction_columns


def held_returns(sim: LaneDriveSim, actions: np.ndarray, gammas: np.ndarray, horizon: int) -> np.ndarray:
    """(n, G): per car the (1 - gamma)-scaled discounted alpha of a branch of `sim` that repeats
    `actions` for `horizon` steps; a car's cumulants are 0 from where it leaves the lane."""
    b = sim.branch()
    g, alive, weight = np.zeros((sim.n, len(gammas))), np.ones(sim.n, bool), np.ones(len(gammas))
    for _ in range(horizon):
        terminated, _ = b.step(actions)
        alive &= ~terminated
        g += (alive * b.alpha)[:, None] * weight * (1.0 - gammas)
        weight = weight * gammas
        if not alive.any() or weight.max() < 1e-6:
            break
    return g


def gvf_steer_slopes(gvf: torch.nn.Module, obs: dict, alpha_columns: slice) -> np.ndarray:
    """(n, G): d v_alpha(s) / d(last steering) of each alpha prediction, by autograd."""
    image, speed, last = (torch.from_numpy(np.asarray(obs[k])) for k in ("image", "speed", "last_action"))
    last = last.clone().requires_grad_(True)
    v = gvf(image, speed, last)[:, alpha_columns]
    columns = [torch.autograd.grad(v[:, j].sum(), last, retain_graph=True)[0][:, 0] for j in range(v.shape[1])]
    return torch.stack(columns, 1).numpy()


def probe_drives(
    sim: LaneDriveSim,
    act: ActFn,
    gvf: torch.nn.Module,
    gammas: np.ndarray,
    alpha_columns: slice,
    every: int = 40,
    horizon: int = 300,
    eps: float = 0.05,
    min_offset: float = 0.0,
) -> np.ndarray:
    """Rows (alpha, true slopes (G), GVF slopes (G)) at the probed states (|alpha| >= `min_offset`)
    of the drives of `act` (the checkpoint's policy: `steer_probe.network_act`)."""
    running, rows, step = np.ones(sim.n, bool), [], 0
    while running.any():
        actions = act(sim)[1]
        off = running & (np.abs(sim.alpha) >= min_offset)
        if step % every == 0 and off.any():
            obs = sim.observation()
            last = np.asarray(obs["last_action"], np.float64)
            up, down = last.copy(), last.copy()
            up[:, 0], down[:, 0] = np.clip(last[:, 0] + eps, -1, 1), np.clip(last[:, 0] - eps, -1, 1)
            moved = up[:, 0] - down[:, 0]
            true = (held_returns(sim, up, gammas, horizon) - held_returns(sim, down, gammas, horizon)) / moved[:, None]
            learned = gvf_steer_slopes(gvf, obs, alpha_columns)
            for i in np.flatnonzero(off):
                rows.append((sim.alpha[i], *true[i], *learned[i]))
        running &= ~step_laps(sim, actions)
        step += 1
    return np.asarray(rows, np.float64).reshape(-1, 1 + 2 * len(gammas))


def summarise(rows: np.ndarray, gammas: np.ndarray) -> dict:
    """Per gamma: the share of states where the GVF's slope has the true one's sign, and both medians."""
    k = len(gammas)
    out = {"states": len(rows)}
    if not len(rows):
        return out
    out["mean_abs_alpha"] = float(np.abs(rows[:, 0]).mean())
    for j, gamma in enumerate(gammas):
        true, learned = rows[:, 1 + j], rows[:, 1 + k + j]
        out[f"{gamma:g}"] = {
            "sign_agrees": float((np.sign(true) == np.sign(learned)).mean()),
            "true_positive": float((true > 0).mean()),
            "true_median": float(np.median(true)),
            "gvf_median": float(np.median(learned)),
        }
    return out


def measure_checkpoint(path: Path, cfg: RunConfig | None = None, **probe_kwargs) -> dict:
    state, agent, _, policy, _ = load_probed(path)
    if "alpha" not in agent.cumulants:
        raise SystemExit(f"{path}: the probe reads the alpha predictions; cumulants are {agent.cumulants}")
    gammas = np.asarray(agent.gammas, np.float64)
    sim = sim_on_test_laps(cfg or RunConfig())
    rows = probe_drives(
        sim, network_act(policy), policy.gvf, gammas, prediction_columns(agent, "alpha"), **probe_kwargs
    )
    settings = {"every": 40, "horizon": 300, "eps": 0.05, **probe_kwargs}
    return {"updates": state["core"]["updates"], "probe": settings, **summarise(rows, gammas)}


def report(measured: dict[str, dict]) -> list[str]:
    lines = [
        "Test-lap states, every 40th step of each drive. Per alpha prediction (gamma): the share of "
        "states where d v_alpha / d(last steering) has the sign of the true slope (the steering held, by "
        "central differences on the simulator), the share where the true slope is positive (steering left "
        "moves the offset up), and both medians.",
        "",
        "| checkpoint | updates | states | gamma | sign agrees | true > 0 | median true | median GVF |",
        "|" + " --- |" * 8,
    ]
    for path, m in measured.items():
        for gamma, g in (
            (key, value) for key, value in m.items() if isinstance(value, dict) and "sign_agrees" in value
        ):
            lines.append(
                f"| {path} | {m['updates']} | {m['states']} | {gamma} | {g['sign_agrees']:.2f} "
                f"| {g['true_positive']:.2f} | {g['true_median']:+.3f} | {g['gvf_median']:+.3f} |"
            )
    return lines


def main(argv: list[str] | None = None) -> None:
    checkpoint_tool(
        argv,
        __doc__,
        "actors.evaluation.prediction_probe",
        measure_checkpoint,
        report,
        "Do the GVFs' alpha predictions slope the true way along the steering?",
    )


if __name__ == "__main__":
    main()
