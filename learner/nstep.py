"""n-step returns for DDPG's target (an option beyond the paper, `scale.n_step`; 1: the paper).

The paper's DDPG backs up one step, r + gamma Q'(s', pi'(s')), so a lane exit's cost reaches the
state n steps before it only after n rounds of backups. With `scale.n_step = n` the target is

  sum_{k<m} gamma^k r_{t+k} + gamma^m (1 - terminated_{t+m-1}) Q'(s_{t+m}, pi'(s_{t+m}))

with m = min(n, steps to the end of the transition's chunk): an actor's chunk holds consecutive
steps of one episode and ends with it (actors.chunker), so the window never crosses an episode.
Uncorrected for the behaviour policy, as in Ape-X DPG and D4PG: the exploration noise and policy
lag of the m - 1 later actions pull the return towards the behaviour's value.

At insert `nstep_columns` gives each transition m ("steps_to_next_obs", the key torchrl's TD(0)
estimator raises gamma to), the discounted reward sum and the flags of step t + m - 1. The replay
stores them beside the transition; the bootstrap state s_{t+m} is the stored next state of slot
(i + m - 1) mod capacity (`ImportanceResamplingReplay.bootstrap`): one insert writes consecutive
ring slots and the ring overwrites slot i before the slots after it, so the bootstrap slot lives
as long as the item. The GVFs keep their one-step targets (Algorithm 1, line 14).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import Tensor

NSTEP_KEYS = ("steps_to_next_obs", "reward_n", "terminated_n", "truncated_n")


def steps_left(lengths: list[int]) -> Tensor:
    """(B, 1) steps from each transition to its chunk's end, itself included, for chunks of `lengths`."""
    if not lengths:
        return torch.zeros(0, 1, dtype=torch.int64)
    return torch.cat([torch.arange(n, 0, -1, dtype=torch.int64) for n in lengths]).reshape(-1, 1)


def _check(left: Tensor) -> None:
    """Refuses a "steps_left" column that does not count down to 1 along every chunk."""
    if left.numel() == 0:
        return
    follows = left[1:] == left[:-1] - 1
    if bool((left < 1).any()) or int(left[-1]) != 1 or not bool(follows[left[:-1] > 1].all()):
        raise ValueError("transitions' steps_left must count down to 1 along each chunk, in time order")


def nstep_columns(transitions: TensorDictBase, n: int, gamma: float) -> dict[str, Tensor]:
    """The n-step columns (NSTEP_KEYS, each (B, 1)) of a batch of time-ordered chunks.

    Transitions without "steps_left" (datasets, tests' rollouts) are their own window: m = 1."""
    nxt = transitions["next"]
    reward, terminated, truncated = nxt["reward"], nxt["terminated"].bool(), nxt["truncated"].bool()
    size = transitions.shape[0]
    if "steps_left" in transitions.keys():
        left = transitions["steps_left"].reshape(-1).to(torch.int64)
        _check(left)
    else:
        left = torch.ones(size, dtype=torch.int64, device=reward.device)
    m = left.clamp(max=n)
    position = torch.arange(size, device=reward.device)
    total = torch.zeros_like(reward)
    for k in range(n):
        inside = (k < m).reshape(-1, 1)
        later = (position + k).clamp(max=max(size - 1, 0))
        total = total + torch.where(inside, gamma**k * reward[later], torch.zeros_like(reward))
    last = position + m - 1
    return {
        "steps_to_next_obs": m.reshape(-1, 1),
        "reward_n": total,
        "terminated_n": terminated[last],
        "truncated_n": truncated[last],
    }
