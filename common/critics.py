"""Critics of GVF-DDPG and the image baselines: `BranchedCritic` ("same structure as the policy
network" with the action as input and a linear output; the paper does not say how two branches
make one Q, so each branch sees the whole input and Q is their sum) and `AdvantageCritic` (the
dueling critic centred on the current actor, `scale.critic_advantage`)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from common.layers import ACTION_DIM, mlp


class BranchedCritic(nn.Module):
    """Q(x, a): sum of `n_branches` MLP branches on [x, a]; linear output (B, 1).

    `reads` keeps only x's first features (GVF-DDPG's `scale.critic_last_action=false` leaves phi's
    last action out). `norm` puts a LayerNorm before each hidden ReLU (Ball et al. 2023): |Q| is then bounded by the
    last layer's weights wherever the input goes, so the actor cannot climb an extrapolation."""

    def __init__(
        self,
        in_dim: int,
        hidden: Sequence[int],
        n_actions: int = ACTION_DIM,
        n_branches: int = 2,
        norm: bool = False,
        reads: int | None = None,
    ):
        super().__init__()
        self.reads = in_dim if reads is None else reads  # x's leading features read; the rest are ignored
        self.branches = nn.ModuleList(mlp(self.reads + n_actions, hidden, 1, norm) for _ in range(n_branches))

    def forward(self, x: Tensor, action: Tensor) -> Tensor:
        xa = torch.cat([x[..., : self.reads], action], -1)
        return torch.stack([branch(xa) for branch in self.branches], 0).sum(0)


class _Unregistered:
    """A module held outside the parent's registry: deepcopy (TD3's twin) shares it, state_dict,
    parameters() and reset_parameters() leave it alone."""

    def __init__(self, module: nn.Module):
        self.module = module

    def __deepcopy__(self, memo: dict) -> _Unregistered:
        return self


class AdvantageCritic(nn.Module):
    """Q(x, a) = V(x) + A(x, a) - A(x, pi(x)): a dueling critic (Wang et al. 2016) centred on the
    current policy, so V is the policy's value and A only the action's part of Q, as advantage
    updating does for fine control periods (Tallec et al. 2019, where a plain Q's action slope
    fades with the step). pi is `centre_on`'s actor, run without gradient; `reads` as BranchedCritic.
    Written here: torchrl has no continuous-action dueling critic."""

    def __init__(
        self,
        in_dim: int,
        hidden: Sequence[int],
        n_actions: int = ACTION_DIM,
        norm: bool = False,
        reads: int | None = None,
    ):
        super().__init__()
        self.reads = in_dim if reads is None else reads
        self.value = mlp(self.reads, hidden, 1, norm)
        self.advantage = mlp(self.reads + n_actions, hidden, 1, norm)
        self._policy: _Unregistered | None = None

    def centre_on(self, policy: nn.Module) -> AdvantageCritic:
        self._policy = _Unregistered(policy)
        return self

    def forward(self, x: Tensor, action: Tensor) -> Tensor:
        if self._policy is None:
            raise RuntimeError("AdvantageCritic needs centre_on(actor) before its first call")
        with torch.no_grad():
            reference = self._policy.module(x)
        read = x[..., : self.reads]
        return (
            self.value(read)
            + self.advantage(torch.cat([read, action], -1))
            - self.advantage(torch.cat([read, reference], -1))
        )
