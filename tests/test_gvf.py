"""GVF learning (learner/gvf.py): targets, tau, rho, and convergence of the
importance-resampling learner to the true out-of-policy values on a chain (paper eq. 5)."""

import math

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from learner.gvf import cumulants, expand_gammas, gvf_loss, importance_ratio, log_tau, td_target
from learner.replay import ImportanceResamplingReplay


def test_td_target_scales_cumulants_and_stops_at_termination():
    gammas = expand_gammas([0.0, 0.9], 2)  # alpha@0, alpha@0.9, beta@0, beta@0.9
    assert gammas.tolist() == pytest.approx([0.0, 0.9, 0.0, 0.9])
    c = cumulants({"alpha": torch.tensor([[0.5], [0.5]]), "beta": torch.tensor([[-1.0], [2.0]])}, ["alpha", "beta"])
    next_v = torch.tensor([[10.0, 20.0, 30.0, 40.0]] * 2)
    terminated = torch.tensor([[False], [True]])
    y = td_target(c, terminated, next_v, gammas)
    expected = torch.tensor(
        [[0.5, 0.1 * 0.5 + 0.9 * 20.0, -1.0, 0.1 * -1.0 + 0.9 * 40.0], [0.5, 0.1 * 0.5, 2.0, 0.1 * 2.0]]
    )
    assert torch.allclose(y, expected)


def test_gvf_loss_gradient_is_rho_bar_times_td_error_times_grad_v():
    torch.manual_seed(0)
    net = nn.Linear(3, 4)
    x, y = torch.randn(8, 3), torch.randn(8, 4)
    gvf_loss(net(x), y, 2.5).backward()
    delta = (net(x) - y).detach()
    expected = 2.5 * (delta.T @ x) / 8  # mean over the batch of rho_bar * delta * grad v
    assert torch.allclose(net.weight.grad, expected, atol=1e-6)


@pytest.mark.parametrize("mean", [0.0, 0.7, 1.0, -1.0])
def test_tau_is_a_density_on_the_box(mean):
    grid = torch.linspace(-1, 1, 801)
    a = torch.cartesian_prod(grid, grid)
    density = log_tau(a, torch.tensor([[mean, -0.3]]).expand(len(a), 2), 0.1).exp()
    cell = (2 / 800) ** 2
    assert abs(float(density.sum()) * cell - 1.0) < 0.01  # trapezoid-free grid sum
    peak = torch.tensor([[mean, -0.3]])
    assert torch.argmax(density) == torch.argmin((a - peak).norm(dim=-1))


def test_importance_ratio_clips_and_reports():
    rho, clipped = importance_ratio(torch.tensor([[0.0], [3.0]]), torch.tensor([[0.0], [0.0]]), 5.0)
    assert torch.allclose(rho, torch.tensor([[1.0], [5.0]]))
    assert clipped.tolist() == [[False], [True]]


# --- the chain: true values under tau are known ------------------------------------------
N_POS, START, WIDTH = 7, 3, 0.1
GAMMAS = [0.0, 0.5, 0.9]
NAMES = ["alpha", "beta"]


def true_values() -> torch.Tensor:
    """v^tau (position, direction) for tau = keep the direction (flips have prob ~ 3e-7)."""
    values = torch.zeros(N_POS, 2, len(NAMES) * len(GAMMAS))
    for pos in range(N_POS):
        for d_index, direction in enumerate((-1, 1)):
            for g_index, gamma in enumerate(GAMMAS):
                ret_alpha = ret_beta = 0.0
                p, discount = pos, 1.0
                while True:
                    p += direction
                    ret_alpha += discount * (1 - gamma) * (p - START) / START
                    ret_beta += discount * (1 - gamma) * direction
                    discount *= gamma
                    if not 0 <= p < N_POS:
                        break
                values[pos, d_index, g_index] = ret_alpha
                values[pos, d_index, len(GAMMAS) + g_index] = ret_beta
    return values


def behaviour_data(n: int, g: torch.Generator) -> TensorDict:
    """mu: keep (half) or flip (half) the last action's sign, both as tau-shaped densities."""
    rows = []
    pos, last = START, 0.5
    for _ in range(n):
        flip = bool(torch.rand(1, generator=g) < 0.5)
        mean = -last if flip else last
        while True:  # exact truncated normal sample on [-1, 1]
            a = mean + WIDTH * float(torch.randn(1, generator=g))
            if -1.0 <= a <= 1.0:
                break
        direction = 1 if a > 0 else -1
        new_pos = pos + direction
        terminated = not 0 <= new_pos < N_POS
        rows.append((pos, last, a, (new_pos - START) / START, direction, terminated))
        # the state keeps the move's direction as its last action, +-0.5 (like an env that
        # quantises actions), so that tau(.|s) depends on s only through that direction
        pos, last = (
            (START, 0.5 if torch.rand(1, generator=g) < 0.5 else -0.5) if terminated else (new_pos, 0.5 * direction)
        )
    pos_, last_, a_, alpha_, beta_, term_ = (torch.tensor(col) for col in zip(*rows))
    state = pos_ * 2 + (last_ > 0).long()
    last_action = last_.float().reshape(-1, 1)
    action = a_.float().reshape(-1, 1)
    next_state = ((pos_ + beta_).clamp(0, N_POS - 1)) * 2 + (action.reshape(-1) > 0).long()
    # mu(a|s) = 0.5 tau(a | last) + 0.5 tau(a | -last): known exactly
    log_mu = torch.logaddexp(log_tau(action, last_action, WIDTH), log_tau(action, -last_action, WIDTH)) + math.log(0.5)
    rho, _ = importance_ratio(log_tau(action, last_action, WIDTH), log_mu, rho_max=100.0)
    return TensorDict(
        {
            "state": state,
            "next_state": next_state,
            "alpha": alpha_.float().reshape(-1, 1),
            "beta": beta_.float().reshape(-1, 1),
            "terminated": term_.reshape(-1, 1),
            "rho": rho,
            "action": action,
            "log_mu": log_mu,
        },
        batch_size=[n],
    )


def train(data: TensorDict, resample: bool, steps: int = 1000) -> torch.Tensor:
    """Tabular GVF (one row per state) trained with the production target and loss."""
    torch.manual_seed(0)
    table = nn.Embedding(N_POS * 2, len(NAMES) * len(GAMMAS))
    nn.init.zeros_(table.weight)
    optimizer = torch.optim.SGD(table.parameters(), lr=2.0)
    replay = ImportanceResamplingReplay(len(data), seed=0)
    replay.extend(data if resample else data.set("rho", torch.ones_like(data["rho"])))
    gammas = expand_gammas(GAMMAS, len(NAMES))
    for step in range(steps):
        batch = replay.sample_by_rho(64)
        with torch.no_grad():
            next_v = table(batch["next_state"])
        target = td_target(cumulants(batch, NAMES), batch["terminated"], next_v, gammas)
        for group in optimizer.param_groups:  # decay: average out the sampling noise
            group["lr"] = 2.0 * (1.0 - step / steps) + 0.05
        optimizer.zero_grad()
        gvf_loss(table(batch["state"]), target, replay.rho_bar if resample else 1.0).backward()
        optimizer.step()
    return table.weight.detach().reshape(N_POS, 2, -1)


def test_importance_resampling_converges_to_the_true_out_of_policy_values():
    data = behaviour_data(10_000, torch.Generator().manual_seed(0))
    truth = true_values()
    assert 0.9 < float(data["rho"].mean()) < 1.1  # rho ~ 2 (keep) or ~ 0 (flip)
    # (position 0, moving right) and (6, moving left) cannot occur: compare visited states
    visited = torch.zeros(N_POS * 2, dtype=torch.bool)
    visited[data["state"]] = True
    visited = visited.reshape(N_POS, 2)
    assert int(visited.sum()) == N_POS * 2 - 2
    corrected = (train(data.clone(), resample=True) - truth)[visited].abs().max()
    plain = (train(data.clone(), resample=False) - truth)[visited].abs().max()
    print(f"max |error|: importance resampling {corrected:.4f}, plain TD {plain:.4f}")
    # values lie in [-4/3, 4/3]; the behaviour-policy values differ from tau's by up to ~1
    assert corrected < 0.01, corrected
    assert plain > 0.3, plain


def test_recorded_returns_for_the_held_out_metric():
    from learner.metrics import recorded_returns

    c = torch.tensor([[1.0], [2.0], [3.0]])
    gammas = expand_gammas([0.0, 0.5], 1)
    end = torch.tensor([False, False, True])
    returns, valid = recorded_returns(c, end, end, gammas)
    assert torch.allclose(returns, torch.tensor([[1.0, 1.375], [2.0, 1.75], [3.0, 1.5]]))
    assert valid.all()  # terminated: nothing is cut off
    returns, valid = recorded_returns(c, torch.zeros(3, dtype=torch.bool), end, gammas, tail_tol=0.2)
    assert torch.allclose(returns[:, 1], torch.tensor([1.375, 1.75, 1.5]))
    assert valid[:, 0].all() and valid[:, 1].tolist() == [True, False, False]  # 0.5^k tail


@pytest.mark.parametrize("terminal", ["absorbing", "zero"])
def test_gvf_converges_to_the_values_of_each_terminal_convention(terminal):
    """A chain of 6 states driven to the right, leaving the lane after the last one, with the
    cumulant 1 (the lane edge) on every transition. With K steps left before the exit, the
    (1-gamma)-scaled return is 1 - gamma^K if the terminal value is 0, and 1 at every state if
    the terminal state repeats its cumulant (absorbing): an imminent exit is fully visible."""
    n, gammas = 6, expand_gammas([0.0, 0.5, 0.9, 0.97], 1)
    v = nn.Parameter(torch.zeros(n, len(gammas)))  # tabular GVF, one row per state
    optimizer = torch.optim.SGD([v], lr=0.5)
    state, nxt = torch.arange(n), torch.arange(1, n + 1).clamp(max=n - 1)
    terminated = (state == n - 1).reshape(-1, 1)
    c = torch.ones(n, 1)
    for _ in range(3000):
        target = td_target(c, terminated, v[nxt].detach(), gammas, terminal)
        optimizer.zero_grad()
        gvf_loss(v[state], target, 1.0).backward()
        optimizer.step()
    steps_left = (n - state).double().reshape(-1, 1)
    expected = torch.ones(n, len(gammas)) if terminal == "absorbing" else 1.0 - gammas.double() ** steps_left
    assert torch.allclose(v.detach().double(), expected.double(), atol=1e-4), (v, expected)


def test_an_unknown_terminal_convention_is_refused():
    with pytest.raises(ValueError, match="terminal"):
        td_target(torch.ones(1, 1), torch.tensor([[True]]), torch.zeros(1, 1), torch.tensor([0.9]), "bounce")
