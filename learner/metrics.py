"""Held-out check of the GVF predictions against recorded returns (issue 3, metrics).

On a held trajectory (consecutive transitions, several episodes allowed) the recorded
return of each (cumulant, gamma) is G_t = (1 - gamma) c_{t+1} + gamma (1 - terminal) G_{t+1}
(the discounted sum of paper eq. 1 with the (1 - gamma) scaling). It is the return of the
*behaviour* policy that drove the trajectory, not of tau; with OU exploration that stays
close to the last action the two are close, which is why the paper tunes the noise so
(appendix, "GVF-DDPG Training"). Steps whose return is cut by the end of the recorded data
(not by a termination) are kept only where gamma^(steps left) <= `tail_tol`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from tensordict import TensorDictBase
from torch import Tensor

from common.config.env import OFF_CENTRE
from learner.gvf import cumulants, expand_gammas


def recorded_returns(
    cumulant: Tensor, terminated: Tensor, done: Tensor, gammas: Tensor, tail_tol: float = 0.01, terminal: str = "zero"
) -> tuple[Tensor, Tensor]:
    """Returns (T, C*G) and a validity mask (T, C*G) of a time-ordered trajectory.

    cumulant (T, C) is c_{t+1} of transition t; terminated and done (T,) end episodes; after a
    termination the return is 0 ("zero") or the last cumulant forever ("absorbing", learner.gvf).
    """
    n_steps, n_cumulants = cumulant.shape
    n_gammas = gammas.shape[0] // n_cumulants
    c = cumulant.repeat_interleave(n_gammas, dim=-1).double()
    gammas = gammas.double()
    returns = torch.zeros_like(c)
    tail_weight = torch.zeros_like(c)  # gamma^(steps to the unknown tail), 0 after a termination
    g_next = torch.zeros_like(c[0])
    w_next = torch.ones_like(c[0])
    for t in range(n_steps - 1, -1, -1):
        if bool(done[t]):  # episode boundary: nothing flows back across it
            absorbing = terminal == "absorbing" and bool(terminated[t])
            g_next = c[t].clone() if absorbing else torch.zeros_like(g_next)
            w_next = torch.zeros_like(w_next) if bool(terminated[t]) else torch.ones_like(w_next)
        returns[t] = (1.0 - gammas) * c[t] + gammas * g_next
        tail_weight[t] = gammas * w_next
        g_next, w_next = returns[t], tail_weight[t]
    return returns.float(), tail_weight <= tail_tol


@torch.no_grad()
def prediction_error(
    gvf: Callable[..., Tensor],
    trajectory: TensorDictBase,
    names: Sequence[str],
    gammas: Sequence[float],
    chunk: int = 256,
    terminal: str = "zero",
) -> dict[str, float]:
    """RMSE of the predictions against recorded returns, per cumulant, and of the best constant.

    Keys: `eval/gvf_return_rmse_<name>`, `eval/constant_return_rmse_<name>` (predicting the
    mean recorded return of each (cumulant, gamma)), both over valid steps and all gammas.
    """
    nxt = trajectory["next"]
    expanded = expand_gammas(gammas, len(names)).to(trajectory.device)
    terminated = nxt["terminated"].reshape(-1)
    returns, valid = recorded_returns(
        cumulants(nxt, names), terminated, terminated | nxt["truncated"].reshape(-1), expanded, terminal=terminal
    )
    predictions = torch.cat(
        [gvf(part["image"], part["speed"], part["last_action"]) for part in trajectory.split(chunk, 0)]
    )
    valid = valid.float()
    count = valid.sum(0).clamp(min=1.0)
    mean = (returns * valid).sum(0) / count
    out: dict[str, float] = {}
    n_gammas = len(gammas)
    for i, name in enumerate(names):
        cols = slice(i * n_gammas, (i + 1) * n_gammas)
        w = valid[:, cols]
        n = w.sum().clamp(min=1.0)
        model = ((predictions[:, cols] - returns[:, cols]).square() * w).sum() / n
        constant = ((mean[cols] - returns[:, cols]).square() * w).sum() / n
        out[f"eval/gvf_return_rmse_{name}"] = float(model.sqrt())
        out[f"eval/constant_return_rmse_{name}"] = float(constant.sqrt())
    return out


def ddpg_metrics(out: TensorDictBase) -> dict[str, float]:
    """DDPG's losses and Q statistics from its loss output (`learner.ddpg.DDPG.loss`); the critic's
    loss includes the steering-slope penalty where one is set, also reported alone."""
    q = out["pred_value"].detach()
    penalty = {"losses/steer_slope": float(out["loss_steer_slope"])} if "loss_steer_slope" in out.keys() else {}
    return penalty | {
        "losses/actor": float(out["loss_actor"].detach()),
        "losses/critic": float(out["loss_value"].detach()),
        "train/q_mean": float(q.mean()),
        "train/q_target_mean": float(out["target_value"].detach().mean()),
        "train/q_min": float(q.min()),
        "train/q_max": float(q.max()),
    }


@torch.no_grad()
def actor_diagnostics(actor: torch.nn.Module, acting: Callable, batch: TensorDictBase) -> dict[str, Tensor]:
    """The actor's gradient norm and how often its output sits at a bound (|a| > 0.99), per action;
    `acting` is the actor's TensorDict module (reads its in_keys from `batch`)."""
    grads = [p.grad for p in actor.parameters() if p.grad is not None]
    action = acting(batch.select(*acting.in_keys))["action"]
    saturated = (action.abs() > 0.99).float().mean(0)
    return {
        "diag/actor_grad_norm": torch.nn.utils.get_total_norm(grads),
        "diag/saturated_steering": saturated[0],
        "diag/saturated_speed": saturated[1],
    }


@torch.no_grad()
def steering_diagnostics(action: Tensor, dq_da: Tensor, alpha: Tensor) -> dict[str, Tensor]:
    """Does the actor follow its critic back to the lane's centre on the training states?

    `action` pi(s) (B, 2), `dq_da` the critic's gradient there (`learner.ddpg.DDPG.action_gradient`),
    `alpha` (B, 1) of the same (mirrored) states. Over the whole batch: the size of dQ/d(steering)
    and dQ/d(target speed). At the off-centre states (|alpha| >= OFF_CENTRE), signed so that
    positive is "towards the centre" (steering against alpha's sign): the share where the critic's
    gradient points there, its mean, and the actor's mean steering. A critic that points to the centre
    with an actor whose steering there does not move is an actor not following it."""
    out = {
        "diag/dq_dsteer_abs": dq_da[:, 0].abs().mean(),
        "diag/dq_dspeed_abs": dq_da[:, 1].abs().mean(),
    }
    alpha = alpha.reshape(-1)
    off = alpha.abs() >= OFF_CENTRE
    out["diag/off_centre_share"] = off.float().mean()
    if bool(off.any()):
        towards = -torch.sign(alpha[off])
        out["diag/critic_to_centre"] = (towards * dq_da[off, 0] > 0).float().mean()
        out["diag/dq_dsteer_to_centre"] = (towards * dq_da[off, 0]).mean()
        out["diag/steer_to_centre"] = (towards * action[off, 0]).mean()
    return out
