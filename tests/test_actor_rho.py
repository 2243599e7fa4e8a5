"""rho where it scales (`learner.rho_at=actor`): actors compute log mu_hat with the broadcast
discriminator, the learner only combines it with tau. The rho stored is the one the learner
would have computed itself with the same weights."""

import dataclasses

import numpy as np
import pytest
import torch

from actors.acting import Acting
from common import wire
from common.config.agent import AgentConfig
from common.config.run import ActorConfig
from common.wire_rules import check_chunk
from learner.core import LearningCore
from learner.ingest import chunks_to_transitions
from learner.ingestor import Ingestor
from tests.core_fixtures import TINY as TINY_SCALE
from tests.helpers import run_inproc
from tests.test_ingestor import inbox

SCALE = TINY_SCALE


def random_chunk(seed: int, steps: int = 12, seq: int = 0) -> wire.TransitionChunk:
    rng = np.random.default_rng(seed)
    return wire.TransitionChunk(
        actor="a",
        env=0,
        episode=seed,
        seq=seq,
        policy_version=0,
        step0=0,
        frames=rng.integers(0, 256, (steps + 2, 64, 128), np.uint8),
        speed=rng.uniform(0, 1, (steps + 1, 1)).astype(np.float32),
        last_action=rng.uniform(-1, 1, (steps + 1, 2)).astype(np.float32),
        action=rng.uniform(-1, 1, (steps, 2)).astype(np.float32),
        reward=rng.uniform(-1, 1, steps).astype(np.float32),
        terminated=np.zeros(steps, bool),
        truncated=np.zeros(steps, bool),
        alpha=rng.uniform(-0.5, 0.5, steps + 1).astype(np.float32),
        beta=rng.uniform(-0.5, 0.5, steps + 1).astype(np.float32),
    )


def broadcast(core: LearningCore, version: int = 7) -> wire.Weights:
    tensors = {k: v.numpy() for k, v in core.broadcast_state_dict(with_behaviour=True).items()}
    return wire.decode(wire.encode(wire.Weights(version, tensors, epoch=1)), expect=wire.Weights)  # as received


@pytest.fixture
def core() -> LearningCore:
    torch.set_num_threads(1)
    core = LearningCore(AgentConfig(name="gvf_ddpg", rho_max=1e6), SCALE, seed=0)
    with torch.no_grad():  # a discriminator far from its initial near-constant output
        for p in core.nets.behaviour.parameters():
            p.mul_(3.0)
    return core


def acting_with(weights: wire.Weights, agent: str = "gvf_ddpg") -> Acting:
    acting = Acting(AgentConfig(name=agent), SCALE, ActorConfig(), 1, seed=0)
    assert acting.load(weights)
    return acting


def test_actor_side_rho_equals_learner_side_rho_for_the_same_discriminator(core):
    acting = acting_with(broadcast(core))
    sent = [acting.with_log_mu(random_chunk(seed)) for seed in range(3)]
    received = [wire.decode(wire.encode(c), expect=wire.TransitionChunk) for c in sent]
    assert all(c.behaviour_version == 7 and c.log_mu.shape == (12,) for c in received)
    with_log_mu = chunks_to_transitions(received, next_image=False)
    core.add(with_log_mu)
    core.add(with_log_mu.exclude("log_mu"))  # the learner's own discriminator forward
    actor_rho, learner_rho = core.replay.rho[:36], core.replay.rho[36:72]
    assert learner_rho.std() > 0.1 * learner_rho.mean()  # rho varies: the comparison means something
    assert torch.allclose(actor_rho, learner_rho, rtol=1e-4)


def test_a_batch_mixing_chunks_with_and_without_log_mu_gets_the_learner_rho_for_all(core):
    acting = acting_with(broadcast(core))
    mixed = chunks_to_transitions([acting.with_log_mu(random_chunk(0)), random_chunk(1)], next_image=False)
    assert torch.isnan(mixed["log_mu"][12:]).all() and torch.isfinite(mixed["log_mu"][:12]).all()
    core.add(mixed)
    core.add(mixed.exclude("log_mu"))
    assert torch.allclose(core.replay.rho[:24], core.replay.rho[24:48], rtol=1e-4)


def test_the_actor_rho_error_against_the_current_g_is_reported(core):
    acting = acting_with(broadcast(core))
    chunk = chunks_to_transitions([acting.with_log_mu(random_chunk(0))], next_image=False)
    core.add(chunk)
    assert core.insert_rho.actor_error == [pytest.approx(0.0, abs=1e-4)]  # same g: no error
    with torch.no_grad():
        for p in core.nets.behaviour.parameters():
            p.add_(0.05)  # g moves on after the broadcast
    for _ in range(20):
        core.add(chunk)
    assert core.insert_rho.actor_error[-1] > 0.05


def test_without_a_broadcast_discriminator_chunks_go_out_unchanged(core):
    acting = Acting(AgentConfig(name="gvf_ddpg"), SCALE, ActorConfig(), 1, seed=0)
    policy_only = {k: v.numpy() for k, v in core.broadcast_state_dict().items()}
    assert acting.load(wire.Weights(1, policy_only, epoch=1))
    chunk = random_chunk(0)
    assert acting.with_log_mu(chunk) is chunk


def test_behaviour_tensors_for_a_policy_without_a_discriminator_are_refused(core):
    acting = Acting(AgentConfig(name="ddpg_image", representation="image"), SCALE, ActorConfig(), 1, seed=0)
    image_core = LearningCore(AgentConfig(name="ddpg_image", representation="image"), SCALE, seed=0)
    tensors = {k: v.numpy() for k, v in image_core.broadcast_state_dict().items()}
    tensors.update({f"behaviour.{k}": v.numpy() for k, v in core.nets.behaviour.state_dict().items()})
    rejects = wire.RejectCounter()
    assert not acting.adopt(wire.Weights(1, tensors, epoch=1), rejects, "k")
    assert rejects.counts["weights"] == 1 and not acting.ready


def test_log_mu_on_the_wire_is_checked(core):
    chunk = acting_with(broadcast(core)).with_log_mu(random_chunk(0))
    m = wire.msgpack.unpackb(wire.encode(chunk))
    del m["behaviour_version"]
    with pytest.raises(wire.WireError, match="come together"):
        wire.decode(wire.msgpack.packb(m))
    far = dataclasses.replace(chunk, log_mu=np.full(12, -80.0, np.float32))
    with pytest.raises(wire.WireError, match="log_mu"):
        check_chunk(far)


def test_a_learner_that_computes_rho_itself_ignores_log_mu_from_actors(core):
    chunk = acting_with(broadcast(core)).with_log_mu(random_chunk(0))
    intake = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64, accept_log_mu=False)
    batch = intake.take(inbox(wire.encode(chunk)), inbox(), updates=100)
    assert "log_mu" not in batch.keys() and intake.progress()["rho_lag"] is None


def test_the_intake_reports_how_old_the_actors_discriminator_is(core):
    chunk = acting_with(broadcast(core, version=40)).with_log_mu(random_chunk(0))
    intake = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64)
    batch = intake.take(inbox(wire.encode(chunk)), inbox(), updates=100)
    assert batch["log_mu"].shape == (12, 1)
    assert intake.progress()["rho_lag"] == 60.0


def test_an_inproc_run_with_rho_at_actor_trains_on_the_actors_log_mu(tmp_path):
    result, ended = run_inproc(["learner.max_updates=30", "learner.rho_at=actor"], tmp_path)
    assert ended and result["updates"] >= 30
    assert result["rejected"] == 0 and result["rho_lag"] is not None  # chunks came with log_mu and were used


def test_log_mu_from_a_discriminator_before_the_warm_start_is_ignored(core):
    """The actors hold the untrained g until the first broadcast after the warm start: their
    log_mu is dropped (the learner's own g decides), a later version's is taken."""
    intake = Ingestor(max_chunk_bytes=1 << 24, ingest_batch=64)
    intake.min_behaviour_version = 1  # what the service sets after a warm start at update 0
    old = acting_with(broadcast(core, version=0)).with_log_mu(random_chunk(0))
    new = acting_with(broadcast(core, version=50)).with_log_mu(random_chunk(1, seq=1))
    batch = intake.take(inbox(wire.encode(old), wire.encode(new)), inbox(), updates=60)
    log_mu = batch["log_mu"].reshape(-1)
    assert torch.isnan(log_mu[:12]).all() and torch.isfinite(log_mu[12:]).all()
