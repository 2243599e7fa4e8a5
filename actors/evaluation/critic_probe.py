"""What did the critic say in the seconds before the policy left the road?

Each checkpoint's policy drives the test and validation roads without exploration, and at every
step its own critic (the first of TD3's twins: the one the actor climbs) is read at phi(s) with
the policy's action and with the target speed swept over its range, the steering kept:

- `q_minus_return`: Q1(s, pi(s)) less the discounted return the drive then collected (DDPG's
  reward: crash penalty, offset weight and reward scale applied). At steps before a crash a critic that charges
  the crash comes out near 0; a large positive gap is a critic that did not see it coming.
- `preferred_speed`: the target speed (m/s) where Q1 peaks along the sweep, less the policy's.
  Negative before a crash: the critic already wanted to slow down and the actor did not follow.
- `dq_dspeed`: the sign of dQ1/d(target speed) at pi(s), the direction the actor's next step moves.
- `dq_dsteer`: the same for the steering. At steps off the centre (|alpha| >= `OFF_CENTRE`)
  `to_centre` is the share where it points back to the centre (steering left, positive, moves
  alpha up): a critic that charges the offset says so there; about half is one that does not.
  `to_centre_mirrored` is the same share at the steps' mirror images (frames flipped, alpha and
  steering negated), which the learner trains on as often as the steps themselves; and
  `steer_asymmetry` the actor's mean |pi(mirrored)_steer + pi_steer| there (0: mirror-equivariant).

"pre-crash" is the window of steps 30 to 5 before a termination (`summarise`'s `before`);
"lapping" is every step of a completed lap at least 300 steps before its end (`horizon`: the
return there is complete to gamma^300). If the creep is a critic that does not (yet, or any more) charge the
fast bends, pre-crash steps show a large positive gap and a preferred speed at or above the
policy's; if it is the actor lagging a critic that does, the preferred speed is below it.

    python -m actors.evaluation.critic_probe runs/crash-penalty-300 runs/default-repeat --last 3 \\
        --cache docs/results/critic-probe.json --out docs/results/critic-probe.md
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from actors.envs.sim import target_speed
from actors.evaluation.evaluate import evaluate
from actors.evaluation.main import eval_env_kwargs
from actors.evaluation.policies import known_config
from actors.evaluation.road_gap import cell, checkpoint_tool, roads
from common import checkpoint
from common.config.agent import AgentConfig, ScaleConfig, shaped_reward, step_sizes
from common.config.env import OFF_CENTRE
from common.config.run import RunConfig
from common.networks import make_networks, phi, steer_negated

SPEED_GRID = torch.linspace(-1.0, 1.0, 21)  # target-speed actions swept at every step
Q_PREFIX = "qvalue_network_params.module."  # torchrl's loss module keeps the critics' weights here


def discounted_returns(rewards: np.ndarray, discount: float) -> np.ndarray:
    """G_t = r_t + discount * G_{t+1}, zero after the last step (a termination or the drive's end)."""
    out, g = np.zeros(len(rewards), np.float64), 0.0
    for t in range(len(rewards) - 1, -1, -1):
        g = rewards[t] + discount * g
        out[t] = g
    return out


def load_critic(state: dict, agent: AgentConfig, scale: ScaleConfig):
    """The acting policy and the critic the actor maximises (TD3's first twin), from a learner checkpoint."""
    nets = make_networks(agent, scale)
    nets.policy.load_state_dict(state["policy"])
    return nets.policy.eval(), twin_critics(state, agent, scale)[0]


def twin_critics(state: dict, agent: AgentConfig, scale: ScaleConfig) -> list[torch.nn.Module]:
    """Every critic of a learner checkpoint: TD3's twins in their stacked order (the loss module
    keeps them stacked (2, ...)), else the one."""
    if not scale.td3:
        critic = make_networks(agent, scale).critic
        critic.load_state_dict(state["core"]["critic"])
        return [critic.eval()]
    loss = state["core"]["ddpg"]["loss"]
    stacked = {k[len(Q_PREFIX) :]: v for k, v in loss.items() if k.startswith(Q_PREFIX)}
    critics = []
    for i in range(next(iter(stacked.values())).shape[0]):
        critic = make_networks(agent, scale).critic
        critic.load_state_dict({k: v[i] for k, v in stacked.items()})
        critics.append(critic.eval())
    return critics


def load_probed(path: Path):
    """A predictive checkpoint's (state, agent, scale, acting policy, critic); others are refused."""
    state = checkpoint.load(checkpoint.find(path))
    agent, scale = known_config(AgentConfig, state["agent"]), known_config(ScaleConfig, state["scale"])
    if agent.representation != "predictive":
        raise SystemExit(f"{path}: the probe reads phi(s); {agent.name} has no predictive representation")
    return (state, agent, scale, *load_critic(state, agent, scale))


def recording_policy(policy: torch.nn.Module, record: list):
    """A PolicyFn of the predictive `policy` that appends each step's (phi, action, phi of the
    mirrored observation) to `record`: the frames flipped left-right and the last steering negated,
    as the learner mirrors its minibatches (`learner.mirror`); the drive itself is not mirrored."""

    @torch.no_grad()
    def act(obs: dict, info: dict) -> np.ndarray:
        image, speed, last = (torch.from_numpy(np.asarray(obs[k])) for k in ("image", "speed", "last_action"))
        x = phi(policy.gvf(image, speed, last), speed, last)
        action = policy.actor(x).clamp(-1.0, 1.0)
        last_m = steer_negated(last)
        x_m = phi(policy.gvf(image.flip(-1), speed, last_m), speed, last_m)
        record.append((x, action, x_m))
        return action.numpy()

    return act


def probe_steps(critic: torch.nn.Module, x: torch.Tensor, action: torch.Tensor) -> dict[str, np.ndarray]:
    """Per step: Q1 at the action, the sweep's best target-speed action, and dQ1/d(steering, target speed)."""
    a = action.clone().requires_grad_(True)
    q = critic(x, a)
    (grad,) = torch.autograd.grad(q.sum(), a)
    with torch.no_grad():
        n, k = len(x), len(SPEED_GRID)
        swept = action.repeat_interleave(k, 0)
        swept[:, 1] = SPEED_GRID.repeat(n)
        q_sweep = critic(x.repeat_interleave(k, 0), swept).reshape(n, k)
    return {
        "q": q.detach().reshape(-1).numpy(),
        "best_speed_action": SPEED_GRID[q_sweep.argmax(1)].numpy(),
        "dq_dspeed": grad[:, 1].numpy(),
        "dq_dsteer": grad[:, 0].numpy(),
    }


def mirrored_probe(policy: torch.nn.Module, critic: torch.nn.Module, x_m: torch.Tensor, action: torch.Tensor):
    """At the mirror images of the steps: dQ1/d(steering) at the mirrored action (steering negated),
    and the actor's own steering there plus its steering at the step (0 for a mirror-equivariant
    actor: `steer_asymmetry`)."""
    mirrored = steer_negated(action)
    with torch.no_grad():
        steer_m = policy.actor(x_m)[:, 0].clamp(-1.0, 1.0)
    return {
        "dq_dsteer_mirrored": probe_steps(critic, x_m, mirrored)["dq_dsteer"],
        "steer_asymmetry": (steer_m + action[:, 0]).numpy(),
    }


def summarise(
    drives: list[dict], probes: list[dict], discount: float, v_max: float, before=(30, 5), horizon: int = 300
) -> dict:
    """Pool the probes of the pre-crash windows and of the lapping steps (see the module doc)."""
    parts: dict[str, list] = {"pre_crash": [], "lapping": []}
    for drive, probe in zip(drives, probes):
        g = discounted_returns(drive["ddpg_reward"], discount)
        n = len(g)
        if drive["metrics"]["lap_completed"] >= 1:
            keep, name = np.arange(max(0, n - horizon)), "lapping"
        elif drive["terminated"]:
            keep, name = np.arange(max(0, n - before[0]), max(0, n - before[1])), "pre_crash"
        else:
            continue
        speed_gap = target_speed(v_max, probe["best_speed_action"]) - target_speed(
            v_max, drive["trace"]["action"][:, 1]
        )
        alpha = drive["trace"]["alpha"][keep]
        centring = -np.sign(alpha) * np.sign(probe["dq_dsteer"][keep])  # +1: Q rises steering to the centre
        # at the mirror image alpha is -alpha: there the centre is the other way
        mirrored = np.sign(alpha) * np.sign(probe.get("dq_dsteer_mirrored", np.full(len(g), np.nan))[keep])
        asymmetry = probe.get("steer_asymmetry", np.full(len(g), np.nan))[keep]
        columns = [probe["q"][keep] - g[keep], speed_gap[keep], np.sign(probe["dq_dspeed"][keep]), alpha, centring]
        parts[name].append(np.stack([*columns, mirrored, asymmetry], 1))
    out = {}
    for name, chunks in parts.items():
        rows = np.concatenate(chunks) if chunks else np.zeros((0, 7))
        off = rows[np.abs(rows[:, 3]) >= OFF_CENTRE]
        out[name] = {
            "drives": len(chunks),
            "steps": len(rows),
            "q_minus_return": float(rows[:, 0].mean()) if len(rows) else None,
            "preferred_speed": float(rows[:, 1].mean()) if len(rows) else None,
            "slower_preferred": float((rows[:, 1] < 0).mean()) if len(rows) else None,
            "dq_dspeed_positive": float((rows[:, 2] > 0).mean()) if len(rows) else None,
            "mean_alpha": float(rows[:, 3].mean()) if len(rows) else None,
            "mean_abs_alpha": float(np.abs(rows[:, 3]).mean()) if len(rows) else None,
            "off_centre_steps": len(off),
            "to_centre": float((off[:, 4] > 0).mean()) if len(off) else None,
            "to_centre_mirrored": float((off[:, 5] > 0).mean()) if len(off) and not np.isnan(off[:, 5]).any() else None,
            "steer_asymmetry": float(np.abs(off[:, 6]).mean()) if len(off) and not np.isnan(off[:, 6]).any() else None,
        }
    return out


def measure_checkpoint(path: Path, cfg: RunConfig | None = None, splits=("test", "validation")) -> dict:
    state, agent, scale, policy, critic = load_probed(path)
    cfg = cfg or RunConfig()
    names = [n for s in splits for n in roads(cfg)[s]]
    record: list = []
    drives = evaluate(
        recording_policy(policy, record), directions=tuple(cfg.eval.directions), tracks=names, **eval_env_kwargs(cfg)
    )
    probes = []
    for i, drive in enumerate(drives):
        n = len(drive["trace"]["reward"])
        x = torch.stack([record[t][0][i] for t in range(n)])
        action = torch.from_numpy(drive["trace"]["action"])
        probe = probe_steps(critic, x, action)
        probe.update(mirrored_probe(policy, critic, torch.stack([record[t][2][i] for t in range(n)]), action))
        probes.append(probe)
        drive["terminated"] = drive["metrics"]["lap_completed"] < 1 and n < cfg.env.max_steps
        terminated = np.zeros(n)
        terminated[-1] = drive["terminated"]
        trace = drive["trace"]
        offset = trace["speed"] / cfg.env.vehicle.v_max * np.abs(trace["alpha"])
        drive["ddpg_reward"] = shaped_reward(trace["reward"], terminated, offset, scale)
    laps = sum(int(d["metrics"]["lap_completed"] >= 1) for d in drives)
    discount = step_sizes(agent, scale)["discount"]
    return {
        "agent": agent.name,
        "updates": state["core"]["updates"],
        "laps": laps,
        "drives": len(drives),
        **summarise(drives, probes, discount, cfg.env.vehicle.v_max),
    }


def report(measured: dict[str, dict]) -> list[str]:
    lines = [
        "| checkpoint | updates | laps | pre-crash steps | Q - G pre-crash | Q - G lapping | preferred - driven "
        "speed pre-crash (m/s) | lapping | slower preferred pre-crash | dQ/dv > 0 pre-crash | lapping |",
        "|" + " --- |" * 11,
    ]
    for path, m in measured.items():
        c, lap = m["pre_crash"], m["lapping"]
        lines.append(
            f"| {path} | {m['updates']} | {m['laps']}/{m['drives']} | {c['steps']} | {cell(c, 'q_minus_return', '.2f')} "
            f"| {cell(lap, 'q_minus_return', '.2f')} | {cell(c, 'preferred_speed', '+.1f')} "
            f"| {cell(lap, 'preferred_speed', '+.1f')} | {cell(c, 'slower_preferred', '.2f')} "
            f"| {cell(c, 'dq_dspeed_positive', '.2f')} | {cell(lap, 'dq_dspeed_positive', '.2f')} |"
        )
    lines += [
        "",
        f"Steering on the laps (|alpha| >= {OFF_CENTRE} counts as off the centre; alpha > 0 is left of it):",
        "",
        "| checkpoint | mean alpha lapping | mean abs(alpha) lapping | off-centre steps | dQ/dsteer to the centre there "
        "| at their mirror images | actor's steering asymmetry there | pre-crash: off-centre steps | to the centre |",
        "|" + " --- |" * 9,
    ]
    for path, m in measured.items():
        c, lap = m["pre_crash"], m["lapping"]
        lines.append(
            f"| {path} | {cell(lap, 'mean_alpha', '+.3f')} | {cell(lap, 'mean_abs_alpha', '.3f')} "
            f"| {cell(lap, 'off_centre_steps', 'd')} | {cell(lap, 'to_centre', '.2f')} "
            f"| {cell(lap, 'to_centre_mirrored', '.2f')} | {cell(lap, 'steer_asymmetry', '.3f')} "
            f"| {cell(c, 'off_centre_steps', 'd')} | {cell(c, 'to_centre', '.2f')} |"
        )
    return lines


def main(argv: list[str] | None = None) -> None:
    checkpoint_tool(
        argv,
        __doc__,
        "actors.evaluation.critic_probe",
        measure_checkpoint,
        report,
        "The critic before each crash, per checkpoint",
    )


if __name__ == "__main__":
    main()
