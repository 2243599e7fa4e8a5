"""The shared replay (learner/replay.py): sampling in proportion to rho (Algorithm 1, line 12)
and the rho_bar bookkeeping (line 11) against exact references."""

import math

import torch
from tensordict import TensorDict

from learner.replay import ImportanceResamplingReplay, compact, expand
from tests.fakes import random_transitions


def items(rho: torch.Tensor, start: int = 0) -> TensorDict:
    n = rho.shape[0]
    return TensorDict(
        {"x": torch.arange(start, start + n).reshape(-1, 1), "rho": rho.reshape(-1, 1).float()}, batch_size=[n]
    )


def chi_square_p_value(counts: torch.Tensor, probs: torch.Tensor) -> float:
    """Pearson chi-square test of `counts` against `probs`; P(X >= stat) with df = k - 1."""
    keep = probs > 0
    expected = probs[keep] * counts.sum()
    stat = ((counts[keep] - expected) ** 2 / expected).sum()
    df = int(keep.sum()) - 1
    return float(torch.special.gammaincc(torch.tensor(df / 2.0, dtype=torch.float64), stat.double() / 2.0))


def test_torchrl_extension_with_the_sum_tree_imports():
    import torchrl._torchrl as ext

    tree = ext.SumSegmentTreeFp32(8)
    tree[torch.arange(3)] = torch.tensor([1.0, 2.0, 3.0])
    assert tree.query(0, 8) == 6.0


def test_rho_bar_is_the_exact_buffer_mean_after_many_inserts_evictions_and_refreshes():
    capacity = 97
    replay = ImportanceResamplingReplay(capacity, seed=0)
    g = torch.Generator().manual_seed(0)
    ring: list[float] = []  # independent model: slot -> rho, cursor wraps
    cursor = 0
    for step in range(400):
        n = int(torch.randint(1, 3 * capacity if step % 50 == 0 else 40, (1,), generator=g))
        rho = (torch.rand(n, generator=g) * 100.0).float()  # float32 exactly as stored
        replay.extend(items(rho))
        for value in rho.double().tolist():
            if len(ring) < capacity:
                ring.append(value)
            else:
                ring[cursor] = value
            cursor = (cursor + 1) % capacity
        if step % 7 == 0 and len(replay) > 5:  # refreshes; a repeated index repeats its value
            index = torch.randperm(len(replay), generator=g)[:10]
            new = torch.rand(10, generator=g).float() * 10.0
            index, new = torch.cat([index, index[:3]]), torch.cat([new, new[:3]])
            replay.update_rho(index, new)
            for i, value in zip(index.tolist(), new.double().tolist()):
                ring[i] = value
        exact = math.fsum(ring) / len(ring)
        assert len(replay) == len(ring)
        assert abs(replay.rho_bar - exact) <= 1e-9 * exact, (step, replay.rho_bar, exact)
    # the sampler's own total mass agrees too (float32 tree, plus eps per item)
    tree_total = replay.buffer.sampler._sum_tree.query(0, capacity)
    assert abs(tree_total - math.fsum(ring)) < 1e-4 * math.fsum(ring)


def test_sampling_frequencies_are_proportional_to_rho():
    rho = torch.tensor([0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 0.25, 3.0, 6.0, 1.5, 0.1, 10.0])
    replay = ImportanceResamplingReplay(16, seed=1)
    replay.extend(items(rho))
    draws = torch.cat([replay.sample_by_rho(1000)["x"].reshape(-1) for _ in range(100)])
    counts = torch.bincount(draws, minlength=12).double()
    probs = rho.double() / rho.sum()
    assert counts[0] == 0  # rho = 0 (plus eps 1e-8): never drawn in 1e5 draws
    assert chi_square_p_value(counts, probs) > 1e-3
    # the same check rejects a uniform sampler, so it has the power to fail
    uniform = torch.full((12,), 1.0 / 12, dtype=torch.float64)
    assert chi_square_p_value(counts, uniform) < 1e-12


def test_refreshed_rho_changes_the_sampling_distribution():
    replay = ImportanceResamplingReplay(8, seed=2)
    replay.extend(items(torch.ones(8)))
    replay.update_rho(torch.tensor([3]), torch.tensor([9.0]))
    draws = torch.cat([replay.sample_by_rho(1000)["index"] for _ in range(40)])
    counts = torch.bincount(draws, minlength=8).double()
    probs = torch.tensor([1, 1, 1, 9, 1, 1, 1, 1], dtype=torch.float64) / 16
    assert chi_square_p_value(counts, probs) > 1e-3
    assert abs(replay.rho_bar - 16 / 8) < 1e-12


def test_uniform_sampling_ignores_rho():
    rho = torch.tensor([0.0, 1.0, 100.0, 5.0, 0.5, 2.0])
    replay = ImportanceResamplingReplay(6, seed=3)
    replay.extend(items(rho))
    draws = torch.cat([replay.sample_uniform(1000)["x"].reshape(-1) for _ in range(60)])
    counts = torch.bincount(draws, minlength=6).double()
    assert chi_square_p_value(counts, torch.full((6,), 1 / 6, dtype=torch.float64)) > 1e-3


def test_compact_storage_expands_back_to_the_transition():
    td = random_transitions(5, seed=4)
    td["next", "image"][:, 1] = td["image"][:, 0]  # the contract: previous frame = frame t
    back = expand(compact(td, torch.ones(5)))
    for key in ["image", "speed", "last_action", "alpha", "beta", "action"]:
        assert torch.equal(back[key], td[key]), key
    for key in ["image", "speed", "alpha", "beta", "reward", "terminated", "truncated"]:
        assert torch.equal(back["next", key], td["next", key]), key
    assert torch.equal(back["next", "last_action"], td["action"])
    assert torch.equal(back["next", "done"], td["next", "terminated"] | td["next", "truncated"])


def test_state_dict_round_trip_keeps_items_and_rho_bar():
    replay = ImportanceResamplingReplay(10, seed=5)
    replay.extend(items(torch.arange(1.0, 15.0)))
    other = ImportanceResamplingReplay(10, seed=6)
    other.load_state_dict(replay.state_dict())
    assert len(other) == 10 and other.rho_bar == replay.rho_bar
    index = torch.arange(10)
    assert torch.equal(other.buffer.storage.get(index)["x"], replay.buffer.storage.get(index)["x"])
    assert torch.equal(other.sample_by_rho(50)["index"], replay.sample_by_rho(50)["index"])


def test_uniform_sampling_with_a_crash_memory_draws_every_item_equally_and_keeps_crashes_past_eviction():
    from learner.replay import CrashMemory, sample_uniform_with

    replay, crashes = ImportanceResamplingReplay(30, seed=0), CrashMemory(10)
    replay.extend(items(torch.ones(30)))  # x 0..29
    crashes.extend(items(torch.ones(10), start=100))  # x 100..109
    replay.extend(items(torch.ones(30), start=30))  # the main ring evicts 0..29; the crash memory keeps its own
    x = torch.cat([sample_uniform_with(replay, crashes, 400)["x"] for _ in range(100)]).reshape(-1)
    assert set(x.tolist()) == set(range(30, 60)) | set(range(100, 110))
    counts = torch.bincount(torch.where(x >= 100, x - 70, x - 30), minlength=40).double()
    assert chi_square_p_value(counts, torch.full((40,), 1 / 40, dtype=torch.float64)) > 1e-4
    assert set(sample_uniform_with(replay, None, 50)["x"].reshape(-1).tolist()) <= set(range(30, 60))
    crashes.extend(items(torch.ones(4), start=200))  # FIFO within the crash memory
    assert len(crashes) == 10 and set(crashes.buffer.storage.get(torch.arange(10))["x"].reshape(-1).tolist()) == set(
        range(104, 110)
    ) | set(range(200, 204))
