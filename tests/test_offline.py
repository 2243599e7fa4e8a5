"""Offline learning (learner.offline, Algorithm 2): the GVFs learned from a fixed dataset reach the
true out-of-policy values of a chain; recorded loading; a gvf-offline policy that gvf-eval drives."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from tensordict import TensorDict

from common.config.agent import AgentConfig
from common.dataset import FIELDS, Dataset, DatasetWriter
from common.networks import GVFNetwork
from learner.offline import BCQBatches, RepresentationTrainer, phi_table, recorded_order
from tests.core_fixtures import TINY
from tests.test_gvf import GAMMAS, N_POS, WIDTH, behaviour_data, train, true_values

CHAIN_SCALE = dataclasses.replace(
    TINY, conv_channels=[2, 2, 2, 2, 2], gvf_hidden=[64, 64], batch_size=32, mirror=0.0, lr_gvf=3e-3, lr_behaviour=3e-3
)


def chain_dataset(root, n: int, shards: int = 4) -> TensorDict:
    """The chain of tests/test_gvf.py as LaneDrive-shaped transitions: the position is the speed
    input (pos / 6), the move's direction the last steering action, the frames are blank; the
    second action dimension is drawn like tau's, so mu and tau differ only in steering."""
    gen = torch.Generator().manual_seed(0)
    chain = behaviour_data(n, gen)
    pos, last = chain["state"] // 2, (chain["state"] % 2).float() - 0.5
    new_pos = chain["next_state"] // 2
    second = (torch.randn(n, 1, generator=gen) * WIDTH).clamp(-1, 1)
    zeros = lambda *shape, dtype=torch.float32: torch.zeros(n, *shape, dtype=dtype)  # noqa: E731
    td = TensorDict(
        {
            "image": zeros(2, 64, 128, dtype=torch.uint8),
            "speed": (pos.float() / (N_POS - 1)).reshape(-1, 1),
            "last_action": torch.cat([last.reshape(-1, 1), zeros(1)], -1),
            "alpha": zeros(1),
            "beta": zeros(1),
            "action": torch.cat([chain["action"], second], -1),
            "next_frame": zeros(1, 64, 128, dtype=torch.uint8),
            "next_speed": (new_pos.float() / (N_POS - 1)).reshape(-1, 1),
            "next_alpha": chain["alpha"],
            "next_beta": chain["beta"],
            "reward": zeros(1),
            "terminated": chain["terminated"].bool(),
            "truncated": zeros(1, dtype=torch.bool),
            "track": zeros(1, dtype=torch.int16),
            "episode": zeros(1, dtype=torch.int64),
            "step": torch.arange(n, dtype=torch.int32).reshape(-1, 1),
            "log_mu": torch.full((n, 1), float("nan")),
        },
        batch_size=[n],
    )
    writer = DatasetWriter(root, "chain")
    for part in td.split(n // shards):
        writer.append(part, ["chain"])
    assert set(td.keys()) == set(FIELDS)
    return chain


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    root = tmp_path_factory.mktemp("chain")
    return chain_dataset(root, 8_000), Dataset.open(root)


def test_offline_algorithm_2_learns_the_chains_true_out_of_policy_values(chain):
    """mu keeps or flips the direction half the time; tau keeps it. From the fixed data and an
    estimated mu, the GVFs must reach tau's values, not the behaviour's (plain TD's)."""
    torch.set_num_threads(1)
    data, dataset = chain
    agent = AgentConfig(name="gvf_ddpg", gammas=GAMMAS, tau_width=WIDTH, rho_max=100.0, metrics_every=10_000)
    trainer = RepresentationTrainer(agent, CHAIN_SCALE, dataset, updates=1500, loading="full", seed=0)
    for _ in range(1500):
        trainer.step()
    assert trainer.loaded == len(dataset) == len(trainer.core.replay)
    states = torch.arange(N_POS * 2)
    pos, last = states // 2, (states % 2).float() - 0.5
    with torch.no_grad():
        v = trainer.core.nets.gvf(
            torch.zeros(len(states), 2, 64, 128, dtype=torch.uint8),
            (pos.float() / (N_POS - 1)).reshape(-1, 1),
            torch.stack([last, torch.zeros(len(states))], -1),
        ).reshape(N_POS, 2, -1)
    visited = torch.zeros(N_POS * 2, dtype=torch.bool)
    visited[data["state"]] = True
    visited = visited.reshape(N_POS, 2)
    truth, plain = true_values(), train(data.clone(), resample=False)
    error = (v - truth)[visited].abs()
    behaviour_gap = (plain - truth)[visited].abs()
    print(f"offline max |error| {error.max():.3f} (mean {error.mean():.3f}); plain TD's {behaviour_gap.max():.3f}")
    assert error.max() < 0.15, error.max()
    assert behaviour_gap.max() > 0.3  # so reaching tau's values is not the behaviour's values by chance
    # g's rho tells the transitions tau would take (keep the direction: rho ~ 2) from the rest (~ 0)
    replay = trainer.core.replay
    stored = replay.buffer.storage.get(torch.arange(len(replay)))
    keep = (stored["action"][:, 0] * stored["last_action"][:, 0] > 0).reshape(-1)
    rho = replay.rho[: len(replay)]
    assert rho[keep].mean() > 20 * rho[~keep].mean(), (rho[keep].mean(), rho[~keep].mean())


def test_recorded_loading_grows_the_replay_in_shard_order_at_a_steady_rate(chain):
    _, dataset = chain
    agent = AgentConfig(name="gvf_ddpg", gammas=GAMMAS, tau_width=WIDTH, behaviour_warmup_updates=5)
    trainer = RepresentationTrainer(
        agent, CHAIN_SCALE, dataset, updates=40, loading="recorded", replay=6_000, start=1_000, load_fraction=0.5
    )
    sizes = []
    for _ in range(40):
        trainer.step()
        sizes.append(trainer.loaded)
    per_update = -(-(8_000 - 1_000) // 20)
    assert sizes[0] == 1_000 + per_update  # warm-up, then the first update's share
    assert sizes[18] - sizes[17] == per_update and sizes[19] == 8_000  # all in at half the updates
    assert len(trainer.core.replay) == 6_000  # a FIFO: the oldest 2,000 left


def test_recorded_order_is_every_shard_whole_in_a_seeded_shuffled_order(chain):
    _, dataset = chain
    out = torch.cat([td["action"] for td in recorded_order(dataset, seed=3)])
    shards = [torch.as_tensor(dataset.shard(i)[0]["action"]) for i in range(len(dataset.shards))]
    pieces = out.split(len(shards[0]))
    order = [next(i for i, s in enumerate(shards) if torch.equal(s, piece)) for piece in pieces]
    assert sorted(order) == list(range(len(shards)))  # each shard once, rows in recorded order
    again = torch.cat([td["action"] for td in recorded_order(dataset, seed=3)])
    other = torch.cat([td["action"] for td in recorded_order(dataset, seed=4)])
    assert torch.equal(out, again) and not torch.equal(out, other)


def test_bcq_minibatches_mirror_the_asked_fraction_phi_from_the_flipped_frames(chain):
    _, dataset = chain
    torch.manual_seed(0)
    gvf = GVFNetwork(CHAIN_SCALE.conv_channels, [8], 4)
    table, mirrored = phi_table(gvf, dataset, 1.0, mirrored=True)
    assert torch.equal(phi_table(gvf, dataset, 1.0)[0]["observation"], table["observation"])
    assert phi_table(gvf, dataset, 1.0)[1] is None
    assert torch.equal(mirrored["action"][:, 0], -table["action"][:, 0])
    assert torch.equal(mirrored["action"][:, 1], table["action"][:, 1])
    assert torch.equal(mirrored["next", "reward"], table["next", "reward"])
    assert torch.equal(mirrored["observation"][:, -2], -table["observation"][:, -2])  # last steering
    assert torch.equal(mirrored["observation"][:, -3], table["observation"][:, -3])  # speed
    plain = BCQBatches.table(table, 1000, seed=1, mirrored=mirrored, mirror=0.0).sample()
    half = BCQBatches.table(table, 1000, seed=1, mirrored=mirrored, mirror=0.5).sample()
    flipped = (half["action"][:, 0] != plain["action"][:, 0]).float().mean()
    assert 0.3 < flipped < 0.7  # rows with a non-zero steering that came from the mirrored table
    assert torch.equal(half["action"][:, 1], plain["action"][:, 1])  # the same rows, drawn alike
    images = BCQBatches.images(dataset, 256, 1.0, seed=2).sample()
    images_all = BCQBatches.images(dataset, 256, 1.0, seed=2, mirror=1.0).sample()
    assert torch.equal(images_all["action"][:, 0], -images["action"][:, 0])
    assert torch.equal(images_all["next", "reward"], images["next", "reward"])


@pytest.mark.parametrize("override", ["scale.offset_weight=2", "scale.crash_penalty=10"])
def test_gvf_offline_refuses_reward_shaping_it_would_not_apply(override, tmp_path):
    from learner.offline_main import train_offline
    from tests.helpers import compose_run

    run = compose_run(["scale=small", override, f"offline.dataset={tmp_path / 'never-opened'}"])
    with pytest.raises(ValueError, match=override.split("=")[0]):
        train_offline(run, tmp_path)
    assert not any(tmp_path.iterdir())  # refused before anything was written


def test_gvf_offline_drops_the_small_scales_crash_penalty_but_keeps_one_asked_for():
    from learner.offline_main import unshaped
    from tests.helpers import compose_run

    small = compose_run(["scale=small"])
    assert small.scale.crash_penalty > 0  # lever G's recipe shapes the online reward
    assert unshaped(small, ["scale=small"]).scale.crash_penalty == 0.0
    asked = compose_run(["scale=small", "scale.crash_penalty=10"])
    assert unshaped(asked, ["scale=small", "scale.crash_penalty=10"]).scale.crash_penalty == 10.0
