"""Offline learning from a logged dataset (`common.dataset`): the paper's second half (appendix
"GVF-BCQ Training", "End-to-end BCQ Baseline Training", Algorithm 2), free of process code.

GVF-BCQ, in two phases as the paper (first half of the updates the predictions, second half
the policy):
1. `RepresentationTrainer` is Algorithm 2: the transitions enter the replay D in recorded
   order (shards in a shuffled order, as the paper shuffled its rosbags), each with
   rho = tau / mu_hat from the discriminator g of that moment (lines 4-10), and every update is
   lines 11-17 of the online learner (`LearningCore.update_representation`): the GVFs by
   importance resampling, g on a uniform minibatch. It is the online code with the action read
   from the file, as the paper says. D is a FIFO of `offline.replay` items that fills from
   `offline.start` on at a steady rate, the last transition entering at `offline.load_fraction`
   of the updates; or with `offline.loading=full` the whole dataset is in D before the first
   update. g's warm start and the rho refreshes every `agent.rho_refresh_every` updates keep rho
   current as g trains (rho is fixed at insert in Algorithm 2; a stale rho biases eq. 5).
2. `phi_table` computes phi(s) = [v(s), speed, last action] of every transition once with the
   trained GVFs (frozen), and BCQ (`learner.bcq`) learns from uniform minibatches of that table.

E2E-BCQ learns BCQ directly on the images (`BCQBatches.images`), as many updates as both
GVF-BCQ phases together (the paper's "fair comparison").
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from common.bcq_networks import flat_observation
from common.config.agent import AgentConfig, ScaleConfig
from common.dataset import Dataset
from common.networks import phi
from learner.core import LearningCore
from learner.mirror import mirror as mirror_batch
from learner.replay import ImportanceResamplingReplay, compact, expand

LOAD_SLICE = 256  # transitions per insert: rho of a slice in one discriminator pass


def recorded_order(dataset: Dataset, seed: int) -> Iterator[TensorDictBase]:
    """Every transition in torchrl's layout, shard by shard in a shuffled order, rows as recorded."""
    order = np.random.default_rng(seed).permutation(len(dataset.shards))
    for i in order:
        shard, _ = dataset.shard(int(i))
        for start in range(0, len(shard), LOAD_SLICE):
            yield expand(shard[start : start + LOAD_SLICE].to_tensordict())


class RepresentationTrainer:
    """Algorithm 2 on a dataset: the GVFs and g of `core` (see the module docstring)."""

    def __init__(
        self,
        agent: AgentConfig,
        scale: ScaleConfig,
        dataset: Dataset,
        *,
        updates: int,
        loading: str = "recorded",
        replay: int = 0,
        start: int = 10_000,
        load_fraction: float = 0.5,
        seed: int = 0,
        device: str = "cpu",
    ):
        capacity = replay or len(dataset)
        warmup = min(start, capacity) if loading == "recorded" else min(len(dataset), capacity)
        self.core = LearningCore(agent, scale, device=device, seed=seed, buffer_size=capacity, warmup=warmup)
        self.source = recorded_order(dataset, seed)
        self.pending: TensorDictBase | None = None
        self.loaded, self.total = 0, len(dataset)
        spread = max(1.0, load_fraction * updates)
        self.per_update = math.ceil(max(self.total - warmup, 0) / spread) if loading == "recorded" else 0
        self.updates = updates

    def load(self, n: int) -> int:
        """Insert the next n transitions of the recorded order (fewer at its end); returns how many."""
        added = 0
        while added < n:
            if self.pending is None:
                self.pending = next(self.source, None)
                if self.pending is None:
                    break
            take = min(n - added, len(self.pending))
            self.core.add(self.pending[:take])
            self.pending = self.pending[take:] if take < len(self.pending) else None
            added += take
        self.loaded += added
        return added

    def step(self) -> dict[str, float]:
        """Fill D to the warm-up, or add this update's share of the data; then one Algorithm 2 update."""
        if not self.core.ready:
            self.load(self.core.warmup - len(self.core.replay))
        if self.per_update:
            self.load(self.per_update)
        metrics = self.core.update_representation()
        if metrics:
            metrics["train/loaded"] = float(self.loaded)
        return metrics


@torch.no_grad()
def phi_table(
    gvf: torch.nn.Module, dataset: Dataset, reward_scale: float, slice_size: int = 512, mirrored: bool = False
) -> tuple[TensorDict, TensorDict | None]:
    """Every transition as BCQ's flat batch: observation phi(s), action, next (observation phi(s'),
    reward * reward_scale, done, terminated), with the GVFs as they are (no gradient). `mirrored`:
    also, from the same pass over the dataset, every transition's left-right mirror image
    (learner.mirror), the GVFs run on the flipped frames; else None in its place."""
    device = next(gvf.parameters()).device
    parts, mirror_parts = [], []
    for shard, _ in dataset:
        for start in range(0, len(shard), slice_size):
            td = expand(shard[start : start + slice_size].to_tensordict()).to(device)
            parts.append(_bcq_item(td, gvf, reward_scale))
            if mirrored:
                flip = torch.ones(len(td), dtype=torch.bool, device=device)
                mirror_parts.append(_bcq_item(mirror_batch(td, flip), gvf, reward_scale))
    return torch.cat(parts).cpu(), torch.cat(mirror_parts).cpu() if mirrored else None


def _bcq_item(td: TensorDictBase, gvf: torch.nn.Module, reward_scale: float) -> TensorDict:
    nxt = td["next"]
    v, v_next = gvf(td["image"], td["speed"], td["last_action"]), gvf(nxt["image"], nxt["speed"], nxt["last_action"])
    return TensorDict(
        {
            "observation": phi(v, td["speed"], td["last_action"]),
            "action": td["action"],
            "next": {
                "observation": phi(v_next, nxt["speed"], nxt["last_action"]),
                "reward": nxt["reward"] * reward_scale,
                "done": nxt["done"],
                "terminated": nxt["terminated"],
            },
        },
        batch_size=td.batch_size,
    )


class BCQBatches:
    """Uniform minibatches for BCQ: from a phi table (GVF-BCQ) or from the images (E2E-BCQ)."""

    def __init__(self, sample):
        self.sample = sample

    @classmethod
    def table(
        cls, table: TensorDict, batch_size: int, seed: int = 0, mirrored: TensorDict | None = None, mirror: float = 0.0
    ) -> BCQBatches:
        """Rows of `table`; with `mirrored` (phi_table's second table), each row independently
        its mirror image with probability `mirror` (the paper's flipped-image augmentation)."""
        g = torch.Generator().manual_seed(seed)

        def sample() -> TensorDict:
            index = torch.randint(len(table), (batch_size,), generator=g)
            batch = table[index]
            if mirrored is not None and mirror > 0:
                flip = torch.rand(batch_size, generator=g) < mirror
                batch[flip] = mirrored[index[flip]]
            return batch

        return cls(sample)

    @classmethod
    def images(
        cls, dataset: Dataset, batch_size: int, reward_scale: float, seed: int = 0, mirror: float = 0.0
    ) -> BCQBatches:
        """The whole dataset in memory in the replay's compact layout (24 KiB a transition); each
        sampled item mirrored left-right (learner.mirror) with probability `mirror`."""
        replay = ImportanceResamplingReplay(len(dataset), seed=seed)
        for td in recorded_order(dataset, seed):
            replay.extend(compact(td, torch.ones(len(td), 1)))
        g = torch.Generator().manual_seed(seed + 1)

        def sample() -> TensorDict:
            td = expand(replay.sample_uniform(batch_size))
            if mirror > 0:
                td = mirror_batch(td, torch.rand(batch_size, generator=g) < mirror)
            nxt = td["next"]
            return TensorDict(
                {
                    "observation": flat_observation(td["image"], td["speed"], td["last_action"]),
                    "action": td["action"],
                    "next": {
                        "observation": flat_observation(nxt["image"], nxt["speed"], nxt["last_action"]),
                        "reward": nxt["reward"] * reward_scale,
                        "done": nxt["done"],
                        "terminated": nxt["terminated"],
                    },
                },
                batch_size=[batch_size],
            )

        return cls(sample)
