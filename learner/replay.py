"""The one shared replay D of GVF-DDPG (Algorithm 1, lines 10-12 and 15; paper eq. 5).

`ImportanceResamplingReplay` is a ring buffer (torchrl `LazyTensorStorage`) with a sum
tree (torchrl `PrioritizedSampler`, alpha = 1, beta = 0, priority = rho), so that

- `sample_by_rho` draws item i with probability rho_i / sum_j rho_j (line 12; the
  sampler adds eps = 1e-8 to every priority, which keeps rho = 0 items legal);
- `sample_uniform` draws uniformly (the discriminator, line 15, and DDPG);
- `rho_bar` is the mean rho over the buffer (line 11), kept as a float64 running sum
  updated on every insert, eviction and rho refresh; a refresh of the whole buffer
  (`slots` + `update_rho`, then `resum_rho`) makes it exact again.

The current rho of slot i is `rho[i]` (and its priority in the sum tree); the "rho" entry
of a stored item is the value it was inserted with.

`CrashMemory` (an option beyond the paper, `scale.crash_memory`) is a second, small ring buffer of
copies of the last steps before each termination: the main ring evicts them after ~90 s of
experience at the small scale, and the policy's speed crept back up once the crashes it caused
had left. DDPG and the discriminator draw their uniform minibatch from both buffers together
(`sample_uniform_with`), each item equally likely, so a crash lives as long as the crash memory
keeps it; the GVFs' sampling by rho (eq. 5) sees the main buffer only; the items it gave are
marked (`FROM_CRASHES`) so that the actor can leave them out (`scale.crash_memory_actor`). Off by
default: with it the swings remained (docs/results.md).

The storage layout of a LaneDrive transition is compact: the next observation's previous
frame is the current frame and its last action is the action, so only the new frame is
stored (`compact` / `expand`, 24 KiB instead of 32 KiB per transition), and frames are
stored as int64 views of their bytes (8 pixels a word), which torchrl writes ~5x faster.

Input transitions use torchrl's convention, a TensorDict of batch (B,) with
  image uint8 (B, 2, 64, 128) [frame t, frame t-1], speed (B, 1), last_action (B, 2),
  alpha (B, 1), beta (B, 1) (info at s_t; only DDPG-LowDim reads them), action (B, 2),
  ("next", image | speed | alpha | beta | reward | terminated | truncated).
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor
from torchrl.data import LazyTensorStorage, PrioritizedSampler, TensorDictReplayBuffer

from learner.nstep import NSTEP_KEYS

FROM_CRASHES = "from_crash_memory"  # (B,) bool of a uniform minibatch: the item is a crash memory's copy
PRIORITY_EPS = 1e-8


class ImportanceResamplingReplay:
    """Ring buffer of TensorDicts carrying a "rho" entry (B, 1); see the module docstring."""

    def __init__(self, capacity: int, *, device: str | torch.device = "cpu", seed: int | None = None):
        self.capacity = capacity
        self.generator = torch.Generator()
        if seed is not None:
            self.generator.manual_seed(seed)
        self.buffer = TensorDictReplayBuffer(
            storage=LazyTensorStorage(capacity, device=device),
            # float32 tree: torchrl 0.14's float64 tree rejects its own default priority
            sampler=PrioritizedSampler(capacity, alpha=1.0, beta=0.0, eps=PRIORITY_EPS, device="cpu"),
            priority_key="rho",
            generator=self.generator,
        )
        # rho of every slot, the source of the running sum's evictions
        self.rho = torch.zeros(capacity, dtype=torch.float64)
        self._rho_sum = 0.0

    def __len__(self) -> int:
        return len(self.buffer)

    @property
    def rho_bar(self) -> float:
        """Mean rho over the items in the buffer (Algorithm 1, line 11)."""
        return self._rho_sum / max(len(self), 1)

    def extend(self, data: TensorDictBase) -> Tensor:
        """Insert a batch (with "rho"); evicts the oldest items once full; returns slot indices."""
        indices = []
        # within one chunk of at most `capacity` items every slot is written once
        for chunk in data.split(self.capacity, 0):
            rho = chunk["rho"].detach().reshape(-1).to(torch.float64).cpu()
            index = self.buffer.extend(chunk).reshape(-1).cpu()
            if "steps_to_next_obs" in chunk.keys():  # n-step bootstraps are found by slot order
                _check_consecutive(index, self.capacity)
            self._rho_sum += float(rho.sum() - self.rho[index].sum())
            self.rho[index] = rho
            indices.append(index)
        return torch.cat(indices)

    def update_rho(self, index: Tensor, rho: Tensor) -> None:
        """Replace the rho of slots `index` (duplicates allowed if their values agree)."""
        index = index.reshape(-1).cpu()
        rho = rho.detach().reshape(-1).to(torch.float64).cpu()
        unique, first = _first_occurrence(index)
        rho = rho[first]
        self._rho_sum += float(rho.sum() - self.rho[unique].sum())
        self.rho[unique] = rho
        self.buffer.update_priority(unique, rho.float())

    def slots(self, size: int):
        """(slot index, items) over every filled slot in slices of `size` (a batched rho refresh)."""
        for start in range(0, len(self), size):
            index = torch.arange(start, min(start + size, len(self)))
            yield index, self.buffer.storage.get(index)

    def resum_rho(self) -> None:
        """rho_bar's sum recomputed exactly from the slots (after a refresh of every slot)."""
        self._rho_sum = float(self.rho[: len(self)].sum())

    def sample_by_rho(self, n: int) -> TensorDictBase:
        """n items with probability rho_i / sum_j rho_j, with their slot "index"."""
        return self.buffer.sample(n)

    def sample_uniform(self, n: int) -> TensorDictBase:
        """n items uniformly at random (with replacement), with their slot "index"."""
        index = torch.randint(len(self), (n,), generator=self.generator)
        data = self.buffer.storage.get(index)
        data["index"] = index
        return data

    def bootstrap(self, stored: TensorDictBase) -> TensorDictBase:
        """The stored items whose next state is the n-step bootstrap state of `stored` (with
        "index" and "steps_to_next_obs"): slot (index + m - 1) mod capacity (learner.nstep)."""
        slot = (stored["index"].reshape(-1) + stored["steps_to_next_obs"].reshape(-1) - 1) % self.capacity
        return self.buffer.storage.get(slot)

    def state_dict(self) -> dict[str, Any]:
        return {
            "buffer": self.buffer.state_dict(),
            "rho": self.rho.clone(),
            "rho_sum": self._rho_sum,
            "generator": self.generator.get_state(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.buffer.load_state_dict(state["buffer"])
        self.rho.copy_(state["rho"])
        self._rho_sum = state["rho_sum"]
        self.generator.set_state(state["generator"])
        # torchrl restores its own copy of the generator: share ours again, one stream
        self.buffer.set_rng(self.generator)


class CrashMemory:
    """FIFO ring (torchrl `LazyTensorStorage`) of compact transitions from just before terminations."""

    def __init__(self, capacity: int, *, device: str | torch.device = "cpu"):
        self.capacity = capacity
        self.buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(capacity, device=device))

    def __len__(self) -> int:
        return len(self.buffer)

    def extend(self, data: TensorDictBase) -> None:
        for chunk in data.split(self.capacity, 0):  # one write per slot, as the main ring
            self.buffer.extend(chunk)

    def state_dict(self) -> dict[str, Any]:
        return self.buffer.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.buffer.load_state_dict(state)


def sample_uniform_with(replay: ImportanceResamplingReplay, crashes: CrashMemory | None, n: int) -> TensorDictBase:
    """n items drawn uniformly from the main replay and the crash memory together (module docstring)."""
    if crashes is None or not len(crashes):
        return replay.sample_uniform(n)
    index = torch.randint(len(replay) + len(crashes), (n,), generator=replay.generator)
    from_crashes = index >= len(replay)
    main = replay.buffer.storage.get(index[~from_crashes])
    extra = crashes.buffer.storage.get(index[from_crashes] - len(replay))
    batch = torch.cat([main, extra], 0)
    batch[FROM_CRASHES] = torch.arange(n) >= main.shape[0]
    return batch


def _check_consecutive(index: Tensor, capacity: int) -> None:
    """One insert must fill consecutive ring slots, or a bootstrap slot would name another item."""
    expected = (index[:1] + torch.arange(index.numel())) % capacity
    if not torch.equal(index, expected):
        raise RuntimeError("the replay wrote one insert to non-consecutive slots: n-step bootstraps would break")


def _first_occurrence(index: Tensor) -> tuple[Tensor, Tensor]:
    """Unique values of `index` and the position of each one's first occurrence."""
    unique, inverse = torch.unique(index, return_inverse=True)
    position = torch.arange(index.numel())
    first = torch.full_like(unique, index.numel()).scatter_reduce(0, inverse, position, reduce="amin")
    return unique, first


def _packed(frames: Tensor) -> Tensor:
    """uint8 frames viewed as int64 (8 pixels a word): the storage's indexed write is ~5x faster."""
    return frames.contiguous().view(torch.int64)


def compact(transitions: TensorDictBase, rho: Tensor) -> TensorDict:
    """Storage layout of a batch of LaneDrive transitions (see the module docstring)."""
    nxt = transitions["next"]
    next_frame = nxt["frame"] if "frame" in nxt.keys() else nxt["image"][:, :1]
    return TensorDict(
        {
            "image": _packed(transitions["image"]),
            "speed": transitions["speed"],
            "last_action": transitions["last_action"],
            "alpha": transitions["alpha"],
            "beta": transitions["beta"],
            "action": transitions["action"],
            "next_frame": _packed(next_frame),
            "next_speed": nxt["speed"],
            "next_alpha": nxt["alpha"],
            "next_beta": nxt["beta"],
            "reward": nxt["reward"],
            "terminated": nxt["terminated"].bool(),
            "truncated": nxt["truncated"].bool(),
            "rho": rho.reshape(-1, 1).float(),
            # the n-step columns where the learner computed them (scale.n_step > 1)
            **{key: transitions[key] for key in NSTEP_KEYS if key in transitions.keys()},
        },
        batch_size=transitions.batch_size[:1],
    )


def expand(stored: TensorDictBase) -> TensorDict:
    """Back to torchrl's convention: the next image is [new frame, frame t]."""
    done = stored["terminated"] | stored["truncated"]
    image = stored["image"].view(torch.uint8)
    marked = {FROM_CRASHES: stored[FROM_CRASHES]} if FROM_CRASHES in stored.keys() else {}
    return TensorDict(
        {
            "image": image,
            "speed": stored["speed"],
            "last_action": stored["last_action"],
            "alpha": stored["alpha"],
            "beta": stored["beta"],
            "action": stored["action"],
            "next": {
                "image": torch.cat([stored["next_frame"].view(torch.uint8), image[:, :1]], 1),
                "speed": stored["next_speed"],
                "last_action": stored["action"],
                "alpha": stored["next_alpha"],
                "beta": stored["next_beta"],
                "reward": stored["reward"],
                "terminated": stored["terminated"],
                "truncated": stored["truncated"],
                "done": done,
            },
            **marked,
        },
        batch_size=stored.batch_size,
    )
